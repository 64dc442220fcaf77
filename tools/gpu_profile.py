"""Where a training step's time goes on a device: each stage's first steps at the `small`
budget under torch.profiler — the top ops by self CPU time, kernel launches and host reads
per step, and how busy the GPU was against the wall clock (a launch-bound step is idle).

    python tools/gpu_profile.py [--device cuda] [--backend triton] [--steps 40]

Run by tools/gpu_check.sh; on a CPU (--device cpu) it profiles the native path the same way.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

from relaygs.cli import one_line_failures
from relaygs.commands.bench_train import bench_scene, flagged_decouple, small_cfg
from relaygs.device import synchronize, usable_device
from relaygs.splat import use_backend
from relaygs.stages import SPECS

LAUNCHES = {"cudaLaunchKernel", "cuLaunchKernel", "cuLaunchKernelEx", "cudaLaunchKernelExC"}
HOST_READS = {"aten::_local_scalar_dense", "cudaStreamSynchronize", "cudaDeviceSynchronize"}


def profile_stage(stage: str, run: Callable[[], None], steps: int, device: torch.device) -> str:
    """Print `stage`'s profile tables; return its one-line summary."""
    run()  # warm: kernels compiled, caches filled
    on_gpu = device.type == "cuda"
    activities = [ProfilerActivity.CPU, *([ProfilerActivity.CUDA] if on_gpu else [])]
    with profile(activities=activities) as prof:
        began = time.perf_counter()
        run()
        synchronize(device)
        wall = time.perf_counter() - began
    events = prof.key_averages()
    launches = sum(e.count for e in events if e.key in LAUNCHES) / steps
    reads = sum(e.count for e in events if e.key in HOST_READS) / steps
    busy = sum(e.self_device_time_total for e in events if e.device_type.name == "CUDA") / 1e6
    line = (
        f"{stage}: {wall:.1f} s for {steps} steps with its setup, {launches:.0f} launches/step, "
        f"{reads:.1f} host reads/step, GPU busy {100 * busy / wall:.0f}%"
    )
    print(f"\n## {line}")
    print(events.table(sort_by="self_cpu_time_total", row_limit=20, max_name_column_width=48))
    if on_gpu:
        print(events.table(sort_by="self_cuda_time_total", row_limit=10, max_name_column_width=48))
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--backend", default="auto")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--cache", type=Path, default=Path("outputs/cache/bench"))
    args = parser.parse_args()
    device = usable_device(args.device, "--device")
    use_backend(args.backend)
    scene = bench_scene(args.cache)
    short = {name: {"steps": args.steps} for name in ("decouple", "relay", "deform")}
    cfg = small_cfg(device=str(device), **short)
    artifacts = {"flagged": flagged_decouple(scene)}
    lines = []
    for stage, upstream in (("decouple", None), ("relay", "flagged"), ("deform", "relay")):
        inputs = {upstream: artifacts[upstream]} if upstream else {}

        def run(stage: str = stage, inputs: dict = inputs) -> None:
            artifacts[stage] = SPECS[stage].run(scene, inputs, cfg)

        lines.append(profile_stage(stage, run, args.steps, device))
    print("; ".join(lines))  # the last line: gpu_check.sh's summary shows it


if __name__ == "__main__":
    sys.exit(one_line_failures(main))
