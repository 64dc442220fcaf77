"""Fake stages for app tests: instant, deterministic, honouring the stage contract (a stage
reads only `seed`, `train` and its own section; artifacts carry a score evaluation reads)."""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from relaygs.app.suite import StageSuite
from relaygs.errors import InputError
from relaygs.paths import config_dir
from relaygs.per_view import PER_VIEW
from relaygs.pipeline import Artifact
from relaygs.pipeline.dag import CanonicalFn
from relaygs.pipeline.spec import pipeline_path
from relaygs.stages import SPECS
from relaygs.stages.common import LOGGED_SCALARS, logged_scalars

STAGE_TYPES = tuple(SPECS)  # conf/config.yaml, which the app tests compose, has a section each
FAKE_CURVE = [[0, {"loss": 1.0}], [5, {"loss": 0.5}]]  # the scalars every fake stage "logged"
TINY_SCENE = ["scene.frames=3", "scene.width=16", "scene.height=9"]


class FakeStages:
    """A StageSuite factory recording which stages ran; a stage whose `(type, cfg)` makes
    `fail_when` true raises a RuntimeError, as a diverging training would."""

    def __init__(
        self,
        canonical: CanonicalFn | None = None,
        fail_when: Callable[[str, dict[str, Any]], bool] | None = None,
        notes: Mapping[str, list[str]] | None = None,
    ) -> None:
        self.calls: list[tuple[str, dict[str, Any]]] = []
        self.evaluations = 0
        self.sinks: list[Any] = []
        self.canonical = canonical or keep_config
        self.fail_when = fail_when
        self.notes = dict(notes or {})

    def suite(self) -> StageSuite:
        """The suite to pass to `run_task`."""
        return StageSuite(
            stages={stage: self._stage(stage) for stage in STAGE_TYPES},
            schema_versions={stage: 1 for stage in STAGE_TYPES},
            canonical=self.canonical,
            validate=validate_config,
            evaluate=self._evaluate,
            render_model=render_model,
            add_sink=self.sinks.append,
            remove_sink=self.sinks.remove,
            logged_scalars=logged_scalars,
        )

    def ran(self, stage: str) -> int:
        """How many times `stage` was built."""
        return sum(1 for name, _ in self.calls if name == stage)

    def _evaluate(self, scene: Any, artifact: Artifact, cfg: dict[str, Any]) -> dict[str, Any]:
        self.evaluations += 1
        return evaluate(scene, artifact, cfg)

    def _stage(self, stage: str):
        def build(scene: Any, upstream: dict[str, Artifact], cfg: dict[str, Any]) -> Artifact:
            assert set(cfg) == {"seed", "train", stage}, cfg
            self.calls.append((stage, cfg))
            if self.fail_when is not None and self.fail_when(stage, cfg):
                raise RuntimeError(f"{stage} diverged: loss is nan\nsecond line")
            for sink in list(self.sinks):
                sink(stage, 0, {"loss": 1.0}, {"render": torch.full((4, 5, 3), 0.5)})
            section = cfg[stage]
            score = sum(a.meta["score"] for a in upstream.values()) + _number(section)
            score += 0.01 * cfg["seed"]
            tensors = {"points": torch.full((10 + len(self.calls), 3), float(score))}
            meta = {"score": score, "metrics": {"score": score}, LOGGED_SCALARS: FAKE_CURVE}
            meta["notes"] = self.notes.get(stage, [])
            return Artifact(stage, tensors, meta)

        return build


def keep_config(stage: str, cfg: Mapping[str, Any], scene: Any) -> Mapping[str, Any]:
    """Every config is its own canonical form."""
    return cfg


def validate_config(stage: str, cfg: Mapping[str, Any]) -> None:
    """The contract's checks on a stage's config: step counts >= 0 and relay.k > 0."""
    section = cfg[stage]
    steps = section.get("steps")
    if steps is not None and (not isinstance(steps, int) or steps < 0):
        raise InputError(f"{stage}.steps: expected a step count >= 0, got {steps!r}")
    if stage == "relay" and not (isinstance(section.get("k"), int) and section["k"] > 0):
        raise InputError(f"relay.k: expected an int >= 1, got {section.get('k')!r}")


def evaluate(scene: Any, artifact: Artifact, cfg: dict[str, Any]) -> dict[str, Any]:
    """Metrics from the artifact's score (so variants differ); per view, cameras 0 and 7 at
    each evaluated frame f, PSNR + f and + 2f."""
    score = float(artifact.meta["score"])
    psnr = 20.0 + score % 7.0
    frames = range(0, scene.num_frames, cfg["eval"]["frame_stride"])
    return {
        "psnr": psnr,
        "ssim": 0.5,
        "fg_psnr": None,
        "render_fps": 100.0,
        "num_gaussians": int(artifact.tensors["points"].shape[0]),
        "eval_frames": len(frames),
        PER_VIEW: [
            {"frame": f, "camera": c, "psnr": psnr + scale * f, "ssim": 0.5, "fg_psnr": None}
            for f in frames
            for c, scale in ((0, 1), (7, 2))
        ],
    }


def render_model(artifact: Artifact, camera: Any, time: float) -> torch.Tensor:
    """A grey image at the camera's size."""
    return torch.full((camera.height, camera.width, 3), time)


def compose_config(overrides: list[str], outputs: Path) -> DictConfig:
    """The app config composed with `overrides`, writing everything under `outputs`."""
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose("config", overrides=[*overrides, f"paths.outputs={outputs}"])


def with_values(config: Mapping[str, Any], **dotted: Any) -> dict[str, Any]:
    """A deep copy of `config` with each value set at its key path (`relay__k=8`: relay.k)."""
    config = copy.deepcopy(dict(config))
    for key, value in dotted.items():
        *parents, leaf = key.split("__")
        functools.reduce(lambda section, part: section[part], parents, config)[leaf] = value
    return config


def pipeline_section(name: str) -> dict[str, Any]:
    """The `pipeline` section that choosing `pipeline=<name>` composes."""
    return yaml.safe_load(pipeline_path(name).read_text(encoding="utf-8"))


def _number(section: Mapping[str, Any]) -> float:
    """A number summarising a section's numeric and boolean values."""
    total = 0.0
    for value in section.values():
        if isinstance(value, bool):
            total += 0.5 if value else 0.0
        elif isinstance(value, int | float):
            total += float(value) / 1000.0
        elif isinstance(value, Mapping):
            total += _number(value)
    return total
