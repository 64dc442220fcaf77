"""`python -m relaygs.bench field`: forward+backward time of the deform stage's motion field at
the `small` budget's settings over N Gaussians (70 % background), per backend, MLP width and
matmul dtype, interleaved against noise, with the training process's allocator settings."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import torch

from relaygs.allocator import keep_freed_memory
from relaygs.cli import int_at_least
from relaygs.commands.bench_timing import add_timing_arguments, interleaved_medians
from relaygs.commands.bench_train import backend_names, small_cfg
from relaygs.field import DeformationField
from relaygs.field.mlp import MATMUL_DTYPES
from relaygs.stages.deform import DeformConfig

HELP = "time the deform stage's motion field"
BACKGROUND_SHARE = 0.7
TIME_ROWS = 32  # ceil(64 frames / 2), the default scene's


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `field` subcommand's options."""
    parser.add_argument(
        "--gaussians", type=int_at_least(1), default=12_800, help="Gaussians the field moves"
    )
    add_timing_arguments(parser)
    parser.add_argument(
        "--widths",
        nargs="+",
        type=int_at_least(1),
        default=None,
        help="MLP widths to time (default: the `small` budget's deform.width)",
    )
    parser.add_argument(
        "--matmul-dtypes",
        nargs="+",
        choices=sorted(MATMUL_DTYPES),
        default=None,
        help="the MLPs' matmul dtypes to time (default: the `small` budget's deform.matmul_dtype)",
    )


def small_field_settings() -> dict[str, Any]:
    """The deform stage's field settings at the `small` budget (grid and MLP, no scene box)."""
    return DeformConfig.from_config(small_cfg()["deform"]).network_settings()


def _field_step(count: int, settings: dict[str, Any]) -> Callable[[], None]:
    """One forward+backward of a field of `settings` (non-zero heads) over `count` Gaussians."""
    generator = torch.Generator().manual_seed(0)
    field = DeformationField([[-2.0] * 3, [2.0] * 3], TIME_ROWS, **settings)
    with torch.no_grad():
        for parameter in field.mlp_sets.parameters():
            parameter.normal_(0.0, 0.05, generator=generator)
    xyz = (torch.rand(count, 3, generator=generator) * 4 - 2).requires_grad_()
    background = int(count * BACKGROUND_SHARE)

    def step() -> None:
        deltas = field(xyz, 0.37, background)
        sum(part.sum() for part in deltas).backward()

    return step


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Median forward+backward milliseconds per MLP variant (width and matmul dtype) and backend;
    the process backend is restored."""
    backends = backend_names(args.backends)
    settings = small_field_settings()
    variants = [
        (width, dtype)
        for width in args.widths or [settings["width"]]
        for dtype in args.matmul_dtypes or [settings["matmul_dtype"]]
    ]
    keep_freed_memory()  # as training does: large temporaries do not fault in their pages again
    torch.set_num_threads(args.threads)
    steps = {
        (width, dtype): _field_step(
            args.gaussians, {**settings, "width": width, "matmul_dtype": dtype}
        )
        for width, dtype in variants
    }
    runs = {(variant, name): steps[variant] for variant in variants for name in backends}
    medians = interleaved_medians(runs, args.repeats)
    return {
        "gaussians": args.gaussians,
        "threads": torch.get_num_threads(),
        "fwd_bwd_ms": {
            variant_label(*variant): {name: medians[variant, name] for name in backends}
            for variant in variants
        },
    }


def variant_label(width: int, matmul_dtype: str) -> str:
    """A report row's name: the MLP width and its matmul dtype, e.g. "128 float32"."""
    return f"{width} {matmul_dtype}"


def print_report(report: dict[str, Any]) -> None:
    """One row per MLP variant, one column per backend, the ratio of the first two backends and,
    with several variants, each row's last backend against the first row's first backend."""
    rows = report["fwd_bwd_ms"]
    first_row = next(iter(rows.values()))
    backends = list(first_row)
    baseline = first_row[backends[0]]
    print(
        f"deformation field forward+backward (ms), {report['gaussians']} Gaussians, "
        f"{report['threads']} threads"
    )
    header = f"{'width dtype':>15}" + "".join(f"{name:>10}" for name in backends)
    if len(backends) >= 2:
        header += f"{'ratio':>8}"
    if len(rows) >= 2:
        header += f"  vs {backends[0]} at {next(iter(rows))}"
    print(header)
    for variant, ms in rows.items():
        line = f"{variant:>15}" + "".join(f"{ms[name]:10.1f}" for name in backends)
        if len(backends) >= 2:
            line += f"{ms[backends[0]] / ms[backends[1]]:7.2f}x"
        if len(rows) >= 2:
            line += f"  {baseline / ms[backends[-1]]:.2f}x"
        print(line)
