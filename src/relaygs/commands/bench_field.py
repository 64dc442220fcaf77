"""`python -m relaygs.bench field`: forward+backward time of the deform stage's motion field at
its defaults over N Gaussians (70 % background), per backend, interleaved against noise."""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import torch

from relaygs.cli import int_at_least
from relaygs.commands.bench_train import backend_names
from relaygs.field import DeformationField
from relaygs.splat import default_backend, use_backend

HELP = "time the deform stage's motion field"
BACKGROUND_SHARE = 0.7
TIME_ROWS = 32  # ceil(64 frames / 2), the default scene's


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `field` subcommand's options."""
    parser.add_argument(
        "--gaussians", type=int_at_least(1), default=12_800, help="Gaussians the field moves"
    )
    parser.add_argument(
        "--repeats", type=int_at_least(1), default=10, help="timed runs per backend (median)"
    )
    parser.add_argument("--threads", type=int_at_least(1), default=2, help="torch CPU threads")
    parser.add_argument(
        "--backends", default="torch,native", help="comma-separated backends (default torch,native)"
    )


def _field_step(count: int) -> Callable[[], None]:
    """One forward+backward of a default-sized field (non-zero heads) over `count` Gaussians."""
    generator = torch.Generator().manual_seed(0)
    field = DeformationField([[-2.0] * 3, [2.0] * 3], TIME_ROWS, isolate_fg_bg=True)
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
    """Median forward+backward milliseconds per backend; the process backend is restored."""
    backends = backend_names(args.backends)
    torch.set_num_threads(args.threads)
    step = _field_step(args.gaussians)
    times: dict[str, list[float]] = {name: [] for name in backends}
    previous = default_backend()
    try:
        for name in backends:  # warm-up: kernels built, allocator caches filled
            use_backend(name)
            step()
        for _ in range(args.repeats):
            for name in backends:
                use_backend(name)
                start = time.perf_counter()
                step()
                times[name].append((time.perf_counter() - start) * 1e3)
    finally:
        use_backend(previous)
    return {
        "gaussians": args.gaussians,
        "threads": torch.get_num_threads(),
        "fwd_bwd_ms": {name: round(statistics.median(t), 2) for name, t in times.items()},
    }


def print_report(report: dict[str, Any]) -> None:
    """One line per backend, and the ratio of the first two."""
    ms = report["fwd_bwd_ms"]
    print(f"deformation field, {report['gaussians']} Gaussians, {report['threads']} threads")
    for name, value in ms.items():
        print(f"{name:<8} forward+backward {value:8.1f} ms")
    if len(ms) >= 2:
        first, second = list(ms.values())[:2]
        print(f"ratio    {first / second:.2f}x")
