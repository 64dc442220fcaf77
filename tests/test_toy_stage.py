"""A stage type added as docs/extending.md shows (this file plays its module, the test registers
its spec), run by the real app as a pipeline on a tiny synthetic scene."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch
from omegaconf import OmegaConf

from fake_stages import TINY_SCENE, compose_config
from refusals import refused
from relaygs import stages
from relaygs.app.task import run_task
from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.common import no_upstream, stage_meta
from relaygs.stages.config import Section, require
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.initial import initial_gaussians
from relaygs.train.scene_model import SceneModel, foreground_with_segments
from relaygs.train.segment_plan import SegmentPlan

STAGE = "points"
SCHEMA_VERSION = 1


@dataclass
class PointsConfig(Section):
    """`cfg["points"]`: the scene's point cloud as static Gaussians, thinned to `init_points`."""

    section: ClassVar[str] = STAGE
    init_points: int = 40
    init_opacity: float = 0.5

    def validate(self) -> None:
        """Check every value range (errors name `points.<key>`), once, when the run is planned."""
        require(self.init_points >= 1, "points.init_points", self.init_points, "an int >= 1")
        require(0 < self.init_opacity < 1, "points.init_opacity", self.init_opacity, "(0, 1)")


def points(scene: Scene, upstream: Mapping[str, Artifact], cfg: Mapping[str, Any]) -> Artifact:
    """The point cloud as an untrained static model (a stage that does not train)."""
    no_upstream(upstream, STAGE)
    section = PointsConfig.from_config(cfg.get(STAGE))
    train = TrainSettings.from_config(cfg.get("train"))
    seed = int(cfg.get("seed", 0))
    background = initial_gaussians(scene, section.init_points, section.init_opacity, 0, seed)
    empty = background.subset(torch.zeros(len(background), dtype=torch.bool))
    model = SceneModel(
        stage=STAGE,
        background=background,
        foreground=foreground_with_segments(empty, torch.zeros(0, dtype=torch.int32)),
        segments=SegmentPlan.uniform(scene.num_frames, scene.num_frames),
        eps2d=train.eps2d,
    )
    metrics = {"num_gaussians": len(background), "num_bg": len(background), "num_fg": 0}
    return model.to_artifact(stage_meta(SCHEMA_VERSION, section, train, None, metrics))


SPEC = StageSpec(name=STAGE, run=points, settings=PointsConfig, schema_version=SCHEMA_VERSION)


@pytest.fixture
def toy_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The app config with the toy stage registered (its line in `SPECS`), its section (what
    `conf/points/default.yaml` gives) and a one-node pipeline file that runs it."""
    monkeypatch.setitem(stages.SPECS, STAGE, SPEC)
    pipeline = tmp_path / "toy.yaml"
    pipeline.write_text("name: toy\nnodes:\n  cloud: {stage: points}\n")
    composed = compose_config([*TINY_SCENE, "budget=smoke"], tmp_path / "outputs")
    config = OmegaConf.to_container(composed, resolve=True)
    config["pipeline"]["name"] = str(pipeline)
    config[STAGE] = {"init_points": 40, "init_opacity": 0.5}
    return config


def test_a_toy_stage_runs_in_a_pipeline_is_scored_reused_and_its_settings_checked(
    toy_config, tmp_path
):
    first = run_task(toy_config, run_dir=tmp_path / "a", original_cwd=tmp_path)
    assert (first["num_gaussians"], first["cache_hits"]) == (40, 0)
    assert math.isfinite(first["psnr"])
    stored = list((tmp_path / "outputs" / "artifacts" / STAGE).iterdir())
    assert len(stored) == 1 and (stored[0] / "manifest.json").is_file()
    again = run_task(toy_config, run_dir=tmp_path / "b", original_cwd=tmp_path)
    assert (again["cache_hits"], again["psnr"]) == (1, first["psnr"])
    toy_config[STAGE]["init_points"] = 0  # out of range: refused before it runs
    with refused(InputError, "points.init_points"):
        run_task(toy_config, run_dir=tmp_path / "run", original_cwd=tmp_path)
    assert not (tmp_path / "run").exists()
