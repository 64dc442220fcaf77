"""`python -m relaygs.bench sweeps`: wall time of the five smoke experiments (target 300 s)."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from relaygs.cli import path_argument

HELP = "time the five experiments at the smoke budget"
TINY_SCENE = ("budget=smoke", "scene.frames=8", "scene.width=48", "scene.height=27")
EXPERIMENTS = ("smoke", "ablation_k", "ablation_components", "baseline", "budget")
TARGET_S = 300.0
ERROR_PREFIX = "error: "
HYDRA_HINT = "Set the environment variable HYDRA_FULL_ERROR"


def command(name: str, outputs: Path, *overrides: str) -> list[str]:
    """The command line of experiment `name` on the tiny scene, writing under `outputs`."""
    experiment = [sys.executable, "-m", "relaygs.run", f"+experiment={name}", *TINY_SCENE]
    return [*experiment, *overrides, f"paths.outputs={outputs}"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `sweeps` subcommand's options."""
    parser.add_argument(
        "--outputs", type=path_argument, help="output folder (default: a temporary one)"
    )


def measure(args: argparse.Namespace) -> dict[str, Any] | None:
    """Time the five experiments in order, in `--outputs` or a temporary folder."""
    if args.outputs is not None:
        return time_experiments(args.outputs.resolve())
    with tempfile.TemporaryDirectory(prefix="relaygs-bench-sweeps-") as folder:
        return time_experiments(Path(folder))


def time_experiments(outputs: Path) -> dict[str, Any] | None:
    """Seconds per experiment and in total (None, after printing why, when one fails)."""
    seconds: dict[str, float] = {}
    for name in EXPERIMENTS:
        started = time.perf_counter()
        done = subprocess.run(command(name, outputs), capture_output=True, text=True)
        seconds[name] = time.perf_counter() - started
        if done.returncode != 0:
            why = failure_line(done.stderr)
            print(f"error: experiment {name!r} exited {done.returncode}: {why}", file=sys.stderr)
            return None
        print(f"{name:<22}{seconds[name]:>8.1f} s", flush=True)
    total = sum(seconds.values())
    return {"seconds": seconds, "total_s": total, "target_s": TARGET_S, "met": total <= TARGET_S}


def failure_line(stderr: str) -> str:
    """Why a child run failed: its last `error: ...` line, else its last line but Hydra's hint."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    errors = [line.removeprefix(ERROR_PREFIX) for line in lines if line.startswith(ERROR_PREFIX)]
    others = [line for line in lines if not line.startswith(HYDRA_HINT)]
    return (errors or others or ["(no output)"])[-1]


def print_report(report: dict[str, Any]) -> None:
    """The total against the target (each experiment's line is printed as it finishes)."""
    verdict = "met" if report["met"] else "MISSED"
    print(f"{'total':<22}{report['total_s']:>8.1f} s  (target ≤ {TARGET_S:.0f} s: {verdict})")
