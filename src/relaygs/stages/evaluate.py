"""The `eval` section, and the evaluation of a final artifact with it (`score_model`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from relaygs.data import Scene
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.config import Section, require
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.evaluate import score_model
from relaygs.train.scene_model import SceneModel


@dataclass(frozen=True)
class EvalSettings(Section):
    """`cfg["eval"]`: evaluate frames 0, stride, 2·stride, …"""

    section: ClassVar[str] = "eval"
    frame_stride: int = 1

    def __post_init__(self) -> None:
        require(self.frame_stride >= 1, "eval.frame_stride", self.frame_stride, "an int >= 1")


def evaluate(scene: Scene, artifact: Artifact, cfg: Mapping[str, Any]) -> dict[str, Any]:
    """Test metrics (`score_model`) of the artifact's model on `scene` with `cfg`'s eval."""
    settings = EvalSettings.from_config(cfg.get("eval"))
    device = TrainSettings.from_config(cfg.get("train")).torch_device()
    model = SceneModel.from_artifact(artifact)
    return score_model(scene, model, settings.frame_stride, device)
