"""`python -m relaygs.bench train`: at the `small` budget on the default scene, each stage's
steps/s per backend (median of interleaved rounds), the deform/decouple step-cost ratio and
(`--full`) the whole pipeline."""

from __future__ import annotations

import argparse
import copy
import itertools
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from relaygs.allocator import keep_freed_memory
from relaygs.cli import int_at_least, path_argument
from relaygs.data import Scene, load_scene
from relaygs.data.synthetic import generate
from relaygs.device import set_threads, usable_device
from relaygs.errors import RelayGSError
from relaygs.model import GaussianSet
from relaygs.pipeline.artifact import Artifact
from relaygs.splat import BACKENDS, default_backend, use_backend
from relaygs.stages import SPECS, evaluate, step_budgets
from relaygs.stages.decouple import DecoupleConfig
from relaygs.stages.train_settings import TrainSettings
from relaygs.train import log
from relaygs.train.scene_model import SceneModel, foreground_with_segments
from relaygs.train.segment_plan import SegmentPlan

HELP = "time the training stages on the default scene"
DEFAULT_CACHE = Path("outputs") / "cache" / "bench"
SCENE = {"preset": "juggle", "frames": 64, "width": 160, "height": 90, "seed": 0}
NO_DENSITY = {"densify_until": 0, "opacity_reset_every": 0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `train` subcommand's options."""
    parser.add_argument(
        "--steps", type=int_at_least(2), default=30, help="steps timed per stage (>= 2)"
    )
    parser.add_argument(
        "--repeats",
        type=int_at_least(1),
        default=3,
        help="rounds of every stage on every backend, interleaved (median; default 3)",
    )
    parser.add_argument("--full", action="store_true", help="also time the whole small pipeline")
    parser.add_argument(
        "--cache", type=path_argument, default=DEFAULT_CACHE, help="scene cache folder"
    )
    parser.add_argument(
        "--threads", type=int_at_least(1), help="torch CPU threads (default: torch's default)"
    )
    parser.add_argument(
        "--device", default="cpu", help="train.device of the timed stages: cpu, cuda or cuda:N"
    )
    parser.add_argument(
        "--backends",
        default="torch,auto",
        help="comma-separated splatting backends the stages are timed on (default torch,auto)",
    )


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """The report: scene, per-stage speeds per backend, step-cost ratio and (--full) pipeline."""
    set_threads(args.threads)
    keep_freed_memory()  # as a run does
    backends = backend_names(args.backends)
    device = str(usable_device(args.device, "--device"))
    scene = bench_scene(args.cache)
    report: dict[str, Any] = {
        "scene": {**SCENE, "points": len(scene.points), "threads": torch.get_num_threads()},
        "device": device,
        "backends": backends,
        "stages": {},
    }
    previous = default_backend()
    rounds: dict[str, list[list[dict[str, Any]]]] = {name: [] for name in backends}
    try:
        for _ in range(args.repeats):
            for name, rows in stage_speeds(scene, args.steps, backends, device).items():
                rounds[name].append(rows)
        report["stages"] = {name: median_rows(rows) for name, rows in rounds.items()}
        report["speedup"] = median_speedups(report["stages"], backends)
        report["ratio"] = step_cost_ratio(scene, args.steps, device)
        if args.full:
            report["full"] = full_pipeline(scene, device)
    finally:
        use_backend(previous)
    return report


def backend_names(text: str) -> list[str]:
    """A comma-separated --backends value as a list, each a splatting backend's name."""
    names = [name for name in text.split(",") if name]
    for name in names:
        if name not in BACKENDS:
            raise RelayGSError(f"unknown backend {name!r}; choose from {', '.join(BACKENDS)}")
    return names


def bench_scene(cache: Path) -> Scene:
    """The default synthetic scene, generated into `cache` when missing."""
    name = "{preset}-{width}x{height}-{frames}f-seed{seed}".format(**SCENE)
    folder = cache.expanduser().absolute() / name
    if not (folder / "scene.json").is_file():
        spec = {k: v for k, v in SCENE.items() if k != "preset"}
        generate(SCENE["preset"], folder, **spec)
    return load_scene(folder)


def small_cfg(
    log_every: int = 10_000, device: str = "cpu", **sections: dict[str, Any]
) -> dict[str, Any]:
    """The `small` budget as a stage cfg on `device`, `sections` merged over it."""
    cfg: dict[str, Any] = copy.deepcopy(step_budgets()["small"])
    cfg["seed"] = 0
    cfg["train"] = {
        "progress": False,
        "log_every": log_every,
        "checkpoint_every": 10_000,
        "device": device,
    }
    for name, values in sections.items():
        cfg[name] = {**cfg.get(name, {}), **values}
    return cfg


def stage_speeds(
    scene: Scene, steps: int, backends: list[str], device: str = "cpu"
) -> dict[str, list[dict[str, Any]]]:
    """Steps/s of each stage over its first `steps` steps on each backend, the backends run back
    to back per stage (this machine's speed drifts over minutes); each stage starts from the
    last backend's upstream, relay from `flagged_decouple` (a short decouple finds no movers)."""
    short = {name: {"steps": steps} for name in ("warmup", "decouple", "relay", "deform")}
    cfg = small_cfg(device=device, **short)
    artifacts: dict[str, Artifact] = {"flagged": flagged_decouple(scene)}
    rows: dict[str, list[dict[str, Any]]] = {name: [] for name in backends}
    for stage, upstream in (
        ("warmup", None),
        ("decouple", None),
        ("relay", "flagged"),
        ("deform", "relay"),
    ):
        inputs = {upstream: artifacts[upstream]} if upstream else {}
        for name in backends:
            use_backend(name)
            artifacts[stage] = SPECS[stage].run(scene, inputs, cfg)
            metrics = artifacts[stage].meta["metrics"]
            rows[name].append(
                {
                    "stage": stage,
                    "steps": steps,
                    "steps_per_s": metrics["steps_per_second"],
                    "gaussians": metrics["num_gaussians"],
                }
            )
    return rows


def median_rows(rounds: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Each stage's row with the median steps/s over `rounds` (and every round's figure)."""
    rows = []
    for per_round in zip(*rounds, strict=True):
        speeds = [row["steps_per_s"] for row in per_round]
        rows.append({**per_round[0], "steps_per_s": statistics.median(speeds), "runs": speeds})
    return rows


def median_speedups(stages: dict[str, list[dict[str, Any]]], backends: list[str]) -> list[float]:
    """Per stage, the median over rounds of the last backend's steps/s over the first's (each
    round's pair ran back to back, so this ratio is steadier than the medians' ratio)."""
    first, last = stages[backends[0]], stages[backends[-1]]
    return [
        statistics.median(b / a for a, b in zip(base["runs"], other["runs"], strict=True))
        for base, other in zip(first, last, strict=True)
    ]


def step_cost_ratio(scene: Scene, steps: int, device: str = "cpu") -> dict[str, Any]:
    """Deform vs decouple median step time on the same initial Gaussians, neither densifying."""
    decouple_cfg = small_cfg(
        log_every=1, device=device, decouple={"steps": steps, "densify": NO_DENSITY}
    )
    decouple_s = median_step_seconds(lambda: SPECS["decouple"].run(scene, {}, decouple_cfg))
    start = flagged_decouple(scene)
    deform_cfg = small_cfg(
        log_every=1,
        device=device,
        deform={"steps": steps, "densify_bg": NO_DENSITY, "densify_fg": NO_DENSITY},
    )
    deform_s = median_step_seconds(
        lambda: SPECS["deform"].run(scene, {"decouple": start}, deform_cfg)
    )
    return {
        "gaussians": start.meta["counts"]["total"],
        "decouple_ms": 1e3 * decouple_s,
        "deform_ms": 1e3 * deform_s,
        "deform_over_decouple": deform_s / decouple_s,
    }


def full_pipeline(scene: Scene, device: str = "cpu") -> dict[str, Any]:
    """Wall time of decouple → relay → deform → evaluation at the small budget."""
    cfg = small_cfg(device=device)
    seconds: dict[str, float] = {}
    artifact: dict[str, Artifact] = {}
    for stage, upstream in (("decouple", None), ("relay", "decouple"), ("deform", "relay")):
        began = time.perf_counter()
        inputs = {upstream: artifact[upstream]} if upstream else {}
        artifact[stage] = SPECS[stage].run(scene, inputs, cfg)
        seconds[stage] = time.perf_counter() - began
        print(f"{stage}: {seconds[stage]:.0f} s", file=sys.stderr, flush=True)
    began = time.perf_counter()
    metrics = evaluate(scene, artifact["deform"], cfg)
    seconds["eval"] = time.perf_counter() - began
    return {
        "seconds": seconds,
        "total_minutes": sum(seconds.values()) / 60.0,
        "counts": {name: a.meta["counts"] for name, a in artifact.items()},
        "metrics": metrics,
    }


def flagged_decouple(scene: Scene) -> Artifact:
    """An untrained decouple artifact: the initial Gaussians split by the cloud's mover flag."""
    section = DecoupleConfig.from_config(small_cfg()["decouple"])
    xyz, rgb, is_fg = scene.points.xyz, scene.points.rgb, scene.points.is_fg
    if section.init_points is not None and len(xyz) > section.init_points:
        keep = torch.randperm(len(xyz), generator=torch.Generator().manual_seed(0))
        keep = keep[: section.init_points].sort().values
        xyz, rgb, is_fg = xyz[keep], rgb[keep], is_fg[keep]
    gaussians = GaussianSet.from_points(xyz, rgb, section.sh_degree, section.init_opacity)
    foreground = gaussians.subset(is_fg)
    model = SceneModel(
        stage="decouple",
        background=gaussians.subset(~is_fg),
        foreground=foreground_with_segments(
            foreground, torch.zeros(len(foreground), dtype=torch.int32)
        ),
        segments=SegmentPlan.uniform(scene.num_frames, scene.num_frames),
        **TrainSettings().blur(),
    )
    return model.to_artifact({})


def median_step_seconds(build: Callable[[], Artifact]) -> float:
    """Median seconds between consecutive logged steps of a stage run."""
    stamps: list[float] = []

    def sink(stage: str, step: int, scalars: Any, images: Any = None) -> None:
        stamps.append(time.perf_counter())

    log.add_sink(sink)
    try:
        build()
    finally:
        log.remove_sink(sink)
    return statistics.median(b - a for a, b in itertools.pairwise(stamps))


def print_report(report: dict[str, Any]) -> None:
    """The scene, each stage's speed per backend, the step-cost ratio and the pipeline's time."""
    scene = report["scene"]
    print(
        f"scene {scene['preset']} {scene['width']}x{scene['height']}, {scene['frames']} frames, "
        f"{scene['points']} points, {scene['threads']} threads, on {report['device']}"
    )
    backends = report["backends"]
    header = f"{'stage':<10}{'steps':>7}{'Gaussians':>11}"
    header += "".join(f"{name + ' steps/s':>16}" for name in backends)
    print(header + (f"{'speed-up':>10}" if len(backends) > 1 else ""))
    for index, row in enumerate(report["stages"][backends[0]]):
        speeds = [report["stages"][name][index]["steps_per_s"] for name in backends]
        line = f"{row['stage']:<10}{row['steps']:>7}{row['gaussians']:>11}"
        line += "".join(f"{speed:>16.2f}" for speed in speeds)
        print(line + (f"{report['speedup'][index]:>9.2f}x" if len(backends) > 1 else ""))
    ratio = report["ratio"]
    print(
        f"step cost at {ratio['gaussians']} Gaussians: decouple {ratio['decouple_ms']:.0f} ms, "
        f"deform {ratio['deform_ms']:.0f} ms, ratio {ratio['deform_over_decouple']:.2f}"
    )
    if "full" in report:
        full = report["full"]
        parts = ", ".join(f"{k} {v:.0f} s" for k, v in full["seconds"].items())
        print(f"small pipeline: {full['total_minutes']:.1f} min ({parts})")
        print(f"test metrics: {json.dumps(full['metrics'])}")
