"""The no_stage2 ablation: S = ceil(T/k) copies of the decoupled foreground, not trained."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from relaygs.data import Scene
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.common import single_upstream, stage_meta, upstream_model
from relaygs.stages.config import Section, require
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.canonical import one_segment_at_most
from relaygs.train.scene_model import SceneModel, replicate_foreground
from relaygs.train.segment_plan import SegmentPlan

STAGE = "replicate"
SCHEMA_VERSION = 1
ACCEPTED_UPSTREAM = ("decouple",)


@dataclass
class ReplicateConfig(Section):
    """`cfg["replicate"]`: the segment length k."""

    section: ClassVar[str] = STAGE
    k: int = 16

    def validate(self) -> None:
        require(self.k >= 1, "replicate.k", self.k, "an int >= 1")


def replicate(scene: Scene, upstream: Mapping[str, Artifact], cfg: Mapping[str, Any]) -> Artifact:
    """Copy the decouple foreground once per segment (copy s tagged s); background unchanged."""
    artifact = single_upstream(upstream, STAGE, ACCEPTED_UPSTREAM)
    section = ReplicateConfig.from_config(cfg.get(STAGE))
    train = TrainSettings.from_config(cfg.get("train"))
    source = upstream_model(artifact, scene, STAGE)
    segments = SegmentPlan.uniform(scene.num_frames, section.k)
    model = SceneModel(
        stage=STAGE,
        background=source.background,
        foreground=replicate_foreground(source.foreground, segments.count),
        segments=segments,
        **source.blur(),
    )
    metrics = {**model.gaussian_counts(), "train_seconds": 0.0}
    return model.to_artifact(stage_meta(SCHEMA_VERSION, section, train, None, metrics))


SPEC = StageSpec(
    STAGE, replicate, ReplicateConfig, SCHEMA_VERSION, ACCEPTED_UPSTREAM, one_segment_at_most
)
