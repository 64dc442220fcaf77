"""Where a training step's time goes on a device: each stage's first steps at the `small`
budget under torch.profiler — the top ops by self CPU time, kernel launches and host reads
per step, and how busy the GPU was against the wall clock (a launch-bound step is idle).

    python tools/gpu_profile.py [--device cuda] [--backend triton] [--steps 40]

Run by tools/gpu_check.sh; on a CPU (--device cpu) it profiles the native path the same way.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

from relaygs.commands.bench_train import bench_scene, flagged_decouple, small_cfg
from relaygs.splat import use_backend
from relaygs.stages import SPECS

LAUNCHES = {"cudaLaunchKernel", "cuLaunchKernel", "cuLaunchKernelEx", "cudaLaunchKernelExC"}
HOST_READS = {"aten::_local_scalar_dense", "cudaStreamSynchronize", "cudaDeviceSynchronize"}


def profile_stage(stage: str, run, steps: int, device: str) -> str:
    """Print `stage`'s profile tables; return its one-line summary."""
    run()  # warm: kernels compiled, caches filled
    activities = [ProfilerActivity.CPU]
    if device.startswith("cuda"):
        activities.append(ProfilerActivity.CUDA)
    with profile(activities=activities) as prof:
        began = time.perf_counter()
        run()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        wall = time.perf_counter() - began
    events = prof.key_averages()
    launches = sum(e.count for e in events if e.key in LAUNCHES) / steps
    reads = sum(e.count for e in events if e.key in HOST_READS) / steps
    busy = sum(e.self_device_time_total for e in events if e.device_type.name == "CUDA") / 1e6
    line = (
        f"{stage}: {1e3 * wall / steps:.1f} ms/step, {launches:.0f} launches/step, "
        f"{reads:.1f} host reads/step, GPU busy {100 * busy / wall:.0f}%"
    )
    print(f"\n## {line}")
    print(events.table(sort_by="self_cpu_time_total", row_limit=20, max_name_column_width=48))
    if device.startswith("cuda"):
        print(events.table(sort_by="self_cuda_time_total", row_limit=10, max_name_column_width=48))
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--backend", default="auto")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--cache", type=Path, default=Path("outputs/cache/bench"))
    args = parser.parse_args()
    use_backend(args.backend)
    scene = bench_scene(args.cache)
    short = {name: {"steps": args.steps} for name in ("decouple", "relay", "deform")}
    cfg = small_cfg(device=args.device, **short)
    artifacts = {"flagged": flagged_decouple(scene)}
    lines = []
    for stage, upstream in (("decouple", None), ("relay", "flagged"), ("deform", "relay")):
        inputs = {upstream: artifacts[upstream]} if upstream else {}

        def run(stage: str = stage, inputs: dict = inputs) -> None:
            artifacts[stage] = SPECS[stage].run(scene, inputs, cfg)

        lines.append(profile_stage(stage, run, args.steps, args.device))
    print("; ".join(lines))  # the last line: gpu_check.sh's summary shows it


if __name__ == "__main__":
    main()
