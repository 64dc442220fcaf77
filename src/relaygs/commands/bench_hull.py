"""`python -m relaygs.bench hull`: forward+backward time of the deform stage's hull term (both
halves, `hull_coverage` > 0) for one frame's copy against its hull, per backend, interleaved
against noise: the nearest-neighbour searches are what it costs."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import torch

from relaygs.cli import int_at_least
from relaygs.commands.bench_timing import add_timing_arguments, interleaved_medians
from relaygs.commands.bench_train import backend_names
from relaygs.stages.frame_hulls import FrameHulls

HELP = "time the deform stage's hull term"
HULL_VOXEL = 0.05  # the tolerance (one hull voxel): it does not change what the searches cost


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `hull` subcommand's options."""
    parser.add_argument(
        "--copy", type=int_at_least(1), default=3000, help="Gaussians of the shown copy"
    )
    parser.add_argument(
        "--hull", type=int_at_least(1), default=4096, help="hull points (the stage keeps 4 096)"
    )
    add_timing_arguments(parser)


def _hull_step(copy: int, hull: int) -> Callable[[], None]:
    """One value and gradient of the hull term for a random copy of `copy` points near a
    random hull of `hull` points."""
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(hull, 3, generator=generator)
    means = (torch.randn(copy, 3, generator=generator) * 1.1).requires_grad_()
    hulls = FrameHulls({0: points}, {0: HULL_VOXEL})

    def step() -> None:
        hulls.distance(means, 0, coverage=1.0).backward()

    return step


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Median forward+backward milliseconds per backend; the process backend is restored."""
    backends = backend_names(args.backends)
    torch.set_num_threads(args.threads)
    step = _hull_step(args.copy, args.hull)
    medians = interleaved_medians({(None, name): step for name in backends}, args.repeats)
    return {
        "copy": args.copy,
        "hull": args.hull,
        "threads": torch.get_num_threads(),
        "fwd_bwd_ms": {name: medians[None, name] for name in backends},
    }


def print_report(report: dict[str, Any]) -> None:
    """One column per backend and the first two backends' ratio."""
    ms = report["fwd_bwd_ms"]
    names = list(ms)
    print(
        f"hull term forward+backward (ms), a copy of {report['copy']} Gaussians, "
        f"{report['hull']} hull points, {report['threads']} threads"
    )
    line = "".join(f"{name:>10}{ms[name]:8.1f}" for name in names)
    if len(names) >= 2:
        line += f"   ratio {ms[names[0]] / ms[names[1]]:.2f}x"
    print(line)
