"""Pieces the stage functions share: upstream lookup, initial Gaussians, training scene, meta."""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from typing import Any

import torch

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.model import MAX_LOG_SCALE, GaussianSet
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.config import json_ready
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.loop import TrainReport
from relaygs.train.scene_model import SceneModel
from relaygs.train.session import SetPlan, TrainingSession

LOGGED_SCALARS = "logged_scalars"
"""Artifact meta key of the scalars a stage emitted while it trained (`ScalarHistory`)."""

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


def initial_gaussians(
    scene: Scene,
    init_points: int | None,
    init_opacity: float,
    sh_degree: int,
    seed: int,
) -> GaussianSet:
    """3DGS initialisation from the scene's point cloud, randomly thinned to `init_points`.

    The cloud's fg flag is not used: foreground is what the stages learn.
    """
    xyz, rgb = scene.points.xyz, scene.points.rgb
    if init_points is not None and xyz.shape[0] > init_points:
        generator = torch.Generator().manual_seed(seed)
        keep = torch.randperm(xyz.shape[0], generator=generator)[:init_points].sort().values
        xyz, rgb = xyz[keep], rgb[keep]
    gaussians = GaussianSet.from_points(
        xyz, rgb, max_sh_degree=sh_degree, init_opacity=init_opacity
    )
    _require_sizes_below_the_cap(scene, gaussians)
    return gaussians


def _require_sizes_below_the_cap(scene: Scene, gaussians: GaussianSet) -> None:
    """One line when most initial Gaussians (sized by their neighbours' distance) are larger
    than the renderer's cap e^MAX_LOG_SCALE: their sizes would get no gradient and stay
    frozen, and the scene would train to nothing. A scene in huge units, to be rescaled."""
    log_scales = gaussians.params["log_scales"].detach()[:, 0]
    over = int((log_scales > MAX_LOG_SCALE).sum())
    if 2 * over > len(log_scales):
        raise InputError(
            f"{scene.root}: {over} of the {len(log_scales)} initial points lie more than "
            f"{math.exp(MAX_LOG_SCALE):.2g} units from their neighbours, the largest Gaussian "
            "the renderer draws; expected a scene in units near metres (rescale the poses' "
            "translations and the point cloud alike)"
        )


def static_session(
    name: str,
    scene: Scene,
    section: Any,
    plan: SetPlan,
    seed: int,
    device: torch.device,
    extras: Mapping[str, float] | None = None,
) -> TrainingSession:
    """The session of a stage that fits one Gaussian set from the scene's point cloud
    (decouple, warmup): `section` gives init_points, init_opacity and sh_degree; `extras`
    adds trainable per-Gaussian scalars at an initial value (decouple's mask logit)."""
    gaussians = initial_gaussians(
        scene, section.init_points, section.init_opacity, section.sh_degree, seed
    )
    for param, value in (extras or {}).items():
        gaussians.add_param(param, torch.full((len(gaussians),), value))
    return TrainingSession(
        sets={name: gaussians.to(device)},
        plans={name: plan},
        extent=scene.extent,
        seed=seed,
        device=device,
    )


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
    """The (step, scalars) records a stage emitted while it trained, from its artifact's meta
    (none for a stage that does not train, or an artifact stored before they were kept)."""
    records = artifact.meta.get(LOGGED_SCALARS, [])
    return [(int(step), dict(scalars)) for step, scalars in records]
