"""`python -m relaygs.bench splat`: forward and forward+backward time of the splatting core."""

from __future__ import annotations

import argparse
import gc
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from relaygs.cli import int_at_least
from relaygs.commands import bench_train
from relaygs.device import synchronize, usable_device
from relaygs.errors import RelayGSError
from relaygs.paths import REPO_ROOT
from relaygs.splat import rasterization

HELP = "time the splatting core"
GARDEN_PATH = REPO_ROOT.parent / "shared" / "data" / "test_garden.npz"


def random_case(n: int, seed: int = 0, size: int = 256) -> dict:
    """The random benchmark scene: N Gaussians in front of one camera at the origin."""
    gen = torch.Generator().manual_seed(seed)
    means = torch.empty(n, 3)
    means[:, :2] = torch.rand(n, 2, generator=gen) * 2 - 1
    means[:, 2] = torch.rand(n, generator=gen) * 2 + 2
    scales = (torch.rand(n, 1, generator=gen) * 0.04 + 0.01).expand(n, 3).contiguous()
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1)
    opacities = torch.rand(n, generator=gen) * 0.8 + 0.1
    colors = torch.rand(n, 3, generator=gen)
    K = torch.tensor([[float(size), 0, size / 2], [0, float(size), size / 2], [0, 0, 1]])
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": opacities,
        "colors": colors,
        "viewmats": torch.eye(4)[None],
        "Ks": K[None],
        "width": size,
        "height": size,
    }


def garden_case(path: Path = GARDEN_PATH, seed: int = 0) -> dict:
    """The shared garden protocol: real means/colours in [-2,2]^3, random shapes, 3 cameras."""
    if not path.is_file():
        raise RelayGSError(
            f"{path}: garden asset not found (expected ../shared/data beside the repo)"
        )
    data = np.load(path)
    means = torch.from_numpy(data["means3d"]).float()
    colors = torch.from_numpy(data["colors"]).float() / 255.0
    keep = (means.abs() <= 2).all(dim=1)
    means, colors = means[keep], colors[keep]
    n = means.shape[0]
    gen = torch.Generator().manual_seed(seed)
    return {
        "means": means,
        "colors": colors,
        "scales": torch.rand(n, 3, generator=gen) * (0.02 - 1e-4) + 1e-4,
        "quats": torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1),
        "opacities": torch.rand(n, generator=gen),
        "viewmats": torch.from_numpy(data["viewmats"]).float(),
        "Ks": torch.from_numpy(data["Ks"]).float(),
        "width": int(data["width"]),
        "height": int(data["height"]),
    }


def _median_ms(fn: Callable[[], None], repeats: int, device: torch.device) -> float:
    """Median milliseconds of `fn` on `device`, each run timed until the device has finished."""
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        synchronize(device)
        start = time.perf_counter()
        fn()
        synchronize(device)
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


CASES: dict[str, Callable[[], dict]] = {
    "random-2k-256": lambda: random_case(2_000),
    "random-10k-256": lambda: random_case(10_000),
    "random-50k-256": lambda: random_case(50_000),
    "garden": garden_case,
}


def _forward_backward(case: dict, backend: str) -> Callable[[], None]:
    learn = ("means", "quats", "scales", "opacities", "colors")

    def run() -> None:
        params = {k: case[k].detach().requires_grad_(True) for k in learn}
        colors, alphas, _ = rasterization(**{**case, **params}, backend=backend)
        (colors.sum() + alphas.sum()).backward()

    return run


def time_splat(case: dict, repeats: int, device: torch.device, backend: str) -> dict:
    """Median forward and forward+backward milliseconds for one scene on one backend."""
    case = {k: v.to(device) if torch.is_tensor(v) else v for k, v in case.items()}

    def forward() -> None:
        with torch.no_grad():
            rasterization(**case, backend=backend)

    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    fwd = _median_ms(forward, repeats, device)
    fwd_bwd = _median_ms(_forward_backward(case, backend), repeats, device)
    if device.type == "cuda":
        peak = torch.cuda.max_memory_allocated(device) / 2**20
    else:
        peak = _cpu_peak_mb(case, backend)
    peak = None if peak is None else round(peak, 1)
    return {"fwd_ms": round(fwd, 2), "fwd_bwd_ms": round(fwd_bwd, 2), "peak_mb": peak}


def _cpu_peak_mb(case: dict, backend: str) -> float | None:
    """Peak resident MB a forward+backward adds, from Linux's peak-RSS counter; else None."""
    status, clear = Path("/proc/self/status"), Path("/proc/self/clear_refs")

    def read_kb(field: str) -> int:
        line = next(x for x in status.read_text().splitlines() if x.startswith(field))
        return int(line.split()[1])

    run = _forward_backward(case, backend)
    run()  # warm-up: kernels loaded, allocator caches filled as in the timed runs
    try:
        gc.collect()
        before = read_kb("VmRSS:")
        clear.write_text("5")
    except (OSError, StopIteration):
        return None
    run()
    return (read_kb("VmHWM:") - before) / 1024.0


def bench_splat(
    repeats: int, device: torch.device, cases: list[str], backends: list[str]
) -> list[dict]:
    """Run the named splat cases on each backend (garden skipped when its file is absent)."""
    results = []
    for name in cases:
        if name not in CASES:
            raise RelayGSError(f"unknown case {name!r}; choose from {', '.join(CASES)}")
        if name == "garden" and not GARDEN_PATH.is_file():
            print(f"skipping garden: {GARDEN_PATH} not found", file=sys.stderr)
            continue
        case = CASES[name]()
        row = {
            "name": name,
            "n_gaussians": int(case["means"].shape[0]),
            "cameras": int(case["viewmats"].shape[0]),
            "width": case["width"],
            "height": case["height"],
            "backends": {b: time_splat(case, repeats, device, b) for b in backends},
        }
        results.append(row)
    return results


def print_report(report: dict) -> None:
    """One line per case: each backend's forward and forward+backward times and peak memory."""
    rows, backends = report["cases"], report["backends"]
    header = f"{'case':<16}{'N':>8}{'cams':>5}{'size':>9}"
    for b in backends:
        header += f"{b + ' fwd':>13}{b + ' f+b':>13}{'MB':>6}"
    if len(backends) == 2:
        header += f"{'f+b ratio':>11}"
    print(header + "   (ms; MB: peak memory a forward+backward adds)")
    for r in rows:
        line = f"{r['name']:<16}{r['n_gaussians']:>8}{r['cameras']:>5}"
        line += f"{str(r['width']) + 'x' + str(r['height']):>9}"
        for b in backends:
            t = r["backends"][b]
            peak = "-" if t["peak_mb"] is None else f"{t['peak_mb']:.0f}"
            line += f"{t['fwd_ms']:>13.1f}{t['fwd_bwd_ms']:>13.1f}{peak:>6}"
        if len(backends) == 2:
            first, second = (r["backends"][b]["fwd_bwd_ms"] for b in backends)
            line += f"{first / second:>10.1f}x"
        print(line)


def add_arguments(splat: argparse.ArgumentParser) -> None:
    """The `splat` subcommand's options."""
    splat.add_argument(
        "--repeats", type=int_at_least(1), default=5, help="timed runs per case (median)"
    )
    splat.add_argument("--device", default="cpu", help="cpu or cuda")
    splat.add_argument(
        "--backends",
        help="comma-separated backends timed side by side (default: torch,native on cpu, "
        "torch,auto on cuda); with two, the table gives the first's forward+backward time over "
        "the second's",
    )
    splat.add_argument(
        "--cases",
        default="random-2k-256,random-10k-256,random-50k-256,garden",
        help="comma-separated case names",
    )


def measure(args: argparse.Namespace) -> dict:
    """The `splat` report: device, threads, backends and one row per case."""
    device = usable_device(args.device, "--device")
    if device.type == "cpu":
        torch.set_num_threads(2)
    default = ["torch", "native"] if device.type == "cpu" else ["torch", "auto"]
    backends = default if args.backends is None else bench_train.backend_names(args.backends)
    rows = bench_splat(args.repeats, device, args.cases.split(","), backends)
    return {
        "device": str(device),
        "threads": torch.get_num_threads(),
        "backends": backends,
        "cases": rows,
    }
