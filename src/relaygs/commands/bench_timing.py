"""What the per-backend micro-benchmarks (`bench field`, `bench hull`) share: their timing
options and a median over rounds that interleave the backends, so machine noise hits all alike."""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Hashable, Mapping

from relaygs.cli import int_at_least
from relaygs.splat import default_backend, use_backend


def add_timing_arguments(parser: argparse.ArgumentParser) -> None:
    """--repeats, --threads and --backends."""
    parser.add_argument(
        "--repeats", type=int_at_least(1), default=10, help="timed runs per backend (median)"
    )
    parser.add_argument("--threads", type=int_at_least(1), default=2, help="torch CPU threads")
    parser.add_argument(
        "--backends", default="torch,native", help="comma-separated backends (default torch,native)"
    )


def interleaved_medians(
    runs: Mapping[tuple[Hashable, str], Callable[[], None]], repeats: int
) -> dict[tuple[Hashable, str], float]:
    """Median milliseconds of each run, keyed (case, backend name), each under its backend: one
    warm-up round (kernels built, caches filled), then `repeats` rounds over every run in turn;
    the process backend is restored."""
    times: dict[tuple[Hashable, str], list[float]] = {key: [] for key in runs}
    previous = default_backend()
    try:
        for (_, backend), run in runs.items():
            use_backend(backend)
            run()
        for _ in range(repeats):
            for key, run in runs.items():
                use_backend(key[1])
                start = time.perf_counter()
                run()
                times[key].append((time.perf_counter() - start) * 1e3)
    finally:
        use_backend(previous)
    return {key: round(statistics.median(values), 2) for key, values in times.items()}
