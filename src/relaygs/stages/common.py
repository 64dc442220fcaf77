"""Pieces the stage functions share: upstream checks, training resolution, artifact meta, rates."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.config import json_ready
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.loop import TrainReport
from relaygs.train.scene_model import SceneModel

LOGGED_SCALARS = "logged_scalars"  # meta key of the scalars logged in training (ScalarHistory)

# 3DGS / 4D-GS per-parameter learning rates (positions × scene extent).
GAUSSIAN_LR: dict[str, Any] = {
    "means": {"init": 1.6e-4, "final": 1.6e-6},
    "log_scales": 5e-3,
    "quats": 1e-3,
    "opacity_logits": 0.05,
    "sh_dc": 2.5e-3,
    "sh_rest": 2.5e-3 / 20,
}
# RelayGS supplement: background positions 2e-4 → 1e-5, foreground 1e-3; the rest as 3DGS.
BACKGROUND_LR: dict[str, Any] = {**GAUSSIAN_LR, "means": {"init": 2e-4, "final": 1e-5}}
FOREGROUND_LR: dict[str, Any] = {**GAUSSIAN_LR, "means": 1e-3}


def single_upstream(
    upstream: Mapping[str, Artifact], stage: str, accepted: Collection[str]
) -> Artifact:
    """The one upstream artifact of a stage, whatever its node name; its type must be accepted."""
    if len(upstream) != 1:
        raise InputError(
            f"stage {stage!r}: expected exactly one upstream artifact, got {sorted(upstream)}"
        )
    artifact = next(iter(upstream.values()))
    if artifact.stage not in accepted:
        raise InputError(
            f"stage {stage!r}: upstream must be one of {sorted(accepted)}, got {artifact.stage!r}"
        )
    return artifact


def no_upstream(upstream: Mapping[str, Artifact], stage: str) -> None:
    """Stages that start from the scene take no upstream artifact."""
    if upstream:
        raise InputError(f"stage {stage!r}: takes no upstream artifact, got {sorted(upstream)}")


def upstream_model(artifact: Artifact, scene: Scene, stage: str) -> SceneModel:
    """The upstream model, checked against the scene's frame count."""
    model = SceneModel.from_artifact(artifact)
    if model.num_frames != scene.num_frames:
        raise InputError(
            f"stage {stage!r}: upstream {artifact.stage!r} has {model.num_frames} frames, "
            f"the scene {scene.num_frames}"
        )
    return model


def training_scene(scene: Scene, train: TrainSettings, early_stage: bool) -> Scene:
    """The scene at the resolution this stage trains at (see TrainSettings.downscale)."""
    width = max(view.camera.width for view in scene.train_views)
    factor = train.downscale_for(width, early_stage)
    return scene if factor == 1 else scene.rescaled(scene.downscale * factor)


def stage_meta(
    schema: int,
    section: Any,
    train: TrainSettings,
    report: TrainReport | None,
    metrics: Mapping[str, Any],
    **extra: Any,
) -> dict[str, Any]:
    """Artifact metadata: schema, config echo, metrics (train report + stage counts), extras."""
    all_metrics = dict(report.metrics()) if report is not None else {}
    all_metrics.update(metrics)
    history = [[step, scalars] for step, scalars in report.history] if report is not None else []
    return {
        "schema": schema,
        "config": {"section": json_ready(section), "train": json_ready(train)},
        "metrics": json_ready(all_metrics),
        LOGGED_SCALARS: history,
        **json_ready(extra),
    }


def logged_scalars(artifact: Artifact) -> list[tuple[int, dict[str, float]]]:
    """The (step, scalars) records a stage emitted while it trained (none if it did not train)."""
    records = artifact.meta.get(LOGGED_SCALARS, [])
    return [(int(step), dict(scalars)) for step, scalars in records]
