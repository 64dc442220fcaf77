"""Stage 1, decouple: a static model of every frame whose learned mask M, off in every view but
frame 0's, drops the frame-0 movers (M = 0: foreground) from the background (docs/method.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import torch
from torch import Tensor

from relaygs.data import Scene
from relaygs.model import (
    BACKGROUND_DENSIFY,
    DensifySettings,
    GaussianSet,
    SetLearningRates,
    paper_schedule,
)
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.common import BACKGROUND_LR, no_upstream, stage_meta, training_scene
from relaygs.stages.config import (
    Section,
    densify_settings,
    learning_rates,
    require,
    require_steps,
    schedule,
)
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.initial import static_session
from relaygs.train.loop import StepResult, run_training
from relaygs.train.loss import photometric_loss
from relaygs.train.render import part_of, splat
from relaygs.train.scene_model import SceneModel, core_only, foreground_with_segments
from relaygs.train.segment_plan import SegmentPlan
from relaygs.train.session import SetPlan
from relaygs.train.views import TrainViews

STAGE = "decouple"
SCHEMA_VERSION = 2  # 2: density control ends before the stage's last step
MASK = "mask_logit"
SET = "all"


@dataclass
class DecoupleConfig(Section):
    """`cfg["decouple"]`: the paper's; ε, mask_lr, frame0_views are ours (docs/method.md)."""

    section: ClassVar[str] = STAGE
    steps: int = 3000
    mask_init: float = 2.0
    mask_threshold: float = 0.5
    mask_lr: float = 0.05
    frame0_views: int = 1
    init_points: int | None = None
    init_opacity: float = 0.1
    sh_degree: int = 3
    sh_every: int = 1000
    lr: dict[str, Any] = field(default_factory=lambda: dict(BACKGROUND_LR))
    densify: dict[str, Any] = field(default_factory=paper_schedule)

    def validate(self) -> None:
        """Check every value range (errors name `decouple.<key>`), once, when the run is planned."""
        require_steps("decouple.steps", self.steps)
        # the logits are float32: NaN, ±inf or 1e300 would stop the training at step 1 (diverged)
        logit, largest = self.mask_init, torch.finfo(torch.float32).max
        require(abs(logit) <= largest, "decouple.mask_init", logit, "a finite float32 logit")
        threshold = self.mask_threshold
        require(0.0 < threshold < 1.0, "decouple.mask_threshold", threshold, "a value in (0, 1)")
        lr = self.mask_lr
        require(0.0 <= lr < math.inf, "decouple.mask_lr", lr, "a finite learning rate >= 0")
        require(self.frame0_views >= 0, "decouple.frame0_views", self.frame0_views, "an int >= 0")
        check_static_settings(self, STAGE)
        self.learning_rates()
        self.densify_settings()

    def learning_rates(self) -> SetLearningRates:
        """Schedules for the Gaussians, the mask logit included."""
        rates = learning_rates(self.lr, self.steps, f"{STAGE}.lr")
        mask = schedule(self.mask_lr, self.steps, f"{STAGE}.mask_lr")
        return replace(rates, extras={**rates.extras, MASK: mask})

    def densify_settings(self) -> DensifySettings:
        """Background density control (the foreground is not known yet)."""
        return densify_settings(self.densify, BACKGROUND_DENSIFY, f"{STAGE}.densify", self.steps)


def check_static_settings(section: Any, stage: str) -> None:
    """Checks shared by the stages that start from the point cloud (decouple, warmup)."""
    points = section.init_points
    require(points is None or points >= 1, f"{stage}.init_points", points, "None or an int >= 1")
    opacity = section.init_opacity
    require(0.0 < opacity < 1.0, f"{stage}.init_opacity", opacity, "an opacity in (0, 1)")
    require(0 <= section.sh_degree <= 3, f"{stage}.sh_degree", section.sh_degree, "0..3")
    require(section.sh_every >= 0, f"{stage}.sh_every", section.sh_every, "an int >= 0")


def straight_through_mask(mask_logit: Tensor, threshold: float) -> Tensor:
    """M = sg(1[σ(m) > ε] − σ(m)) + σ(m): hard 0/1 value, gradient of σ(m)."""
    soft = torch.sigmoid(mask_logit)
    hard = (soft > threshold).to(soft.dtype)
    return (hard - soft).detach() + soft


def decouple(scene: Scene, upstream: Mapping[str, Artifact], cfg: Mapping[str, Any]) -> Artifact:
    """Train the static model with the mask; output background + foreground (`is_fg`)."""
    no_upstream(upstream, STAGE)
    section = DecoupleConfig.from_config(cfg.get(STAGE))
    train = TrainSettings.from_config(cfg.get("train"))
    seed = int(cfg.get("seed", 0))
    device = train.torch_device()
    training = training_scene(scene, train, early_stage=True)
    plan = SetPlan(section.learning_rates(), section.densify_settings(), section.sh_every)
    session = static_session(SET, scene, section, plan, seed, device, {MASK: section.mask_init})
    views = TrainViews(training, device)

    def step_fn(step: int) -> StepResult:
        """Frame-0 views see every Gaussian; the other views see opacity × M."""
        generator = session.generator
        first = min(section.frame0_views, train.batch_views)
        batch = views.random_views_at(0, first, generator) if first else []
        batch += views.random_views(train.batch_views - first, generator)
        gaussians = session.sets[SET]
        degree = gaussians.active_sh_degree
        renders, preds, targets = [], [], []
        for masked in (False, True):
            group = [view for view in batch if (view.frame != 0) == masked]
            if not group:
                continue
            part = part_of(SET, gaussians, degree)
            if masked:
                part.opacity_factor = straight_through_mask(
                    gaussians.params[MASK], section.mask_threshold
                )
            render = splat([part], [view.camera for view in group], degree, **train.blur())
            renders.append(render)
            preds += render.images
            targets += [views.image(view) for view in group]
        loss = photometric_loss(preds, targets, train.ssim_weight)
        return StepResult(loss, renders, preds, targets)

    def counts() -> tuple[int, int]:
        is_fg = _foreground_flags(session.sets[SET], section.mask_threshold)
        return int((~is_fg).sum()), int(is_fg.sum())

    report = run_training(STAGE, session, section.steps, train, step_fn, counts)
    final = session.sets[SET]
    is_fg = _foreground_flags(final, section.mask_threshold)
    foreground = core_only(final.subset(is_fg))
    model = SceneModel(
        stage=STAGE,
        background=core_only(final.subset(~is_fg)),
        foreground=foreground_with_segments(
            foreground, torch.zeros(len(foreground), dtype=torch.int32)
        ),
        segments=SegmentPlan.uniform(scene.num_frames, scene.num_frames),
        **train.blur(),
    )
    n_fg = len(foreground)
    metrics = {**model.gaussian_counts(), "fg_fraction": n_fg / max(len(final), 1)}
    notes = [NO_FOREGROUND_NOTE.format(steps=section.steps)] if n_fg == 0 else []
    meta = stage_meta(
        SCHEMA_VERSION, section, train, report, metrics, downscale=training.downscale, notes=notes
    )
    return model.to("cpu").to_artifact(meta)


NO_FOREGROUND_NOTE = (
    "decouple marked no Gaussian as foreground in its {steps} steps (too few, or nothing "
    "in the scene moves): what follows gets no foreground from it, and a pipeline without "
    "relay copies (no_copies, no_stage2) treats no part of the scene apart"
)


def _foreground_flags(gaussians: GaussianSet, threshold: float) -> Tensor:
    """is_fg = (M == 0), i.e. σ(m) ≤ ε."""
    return torch.sigmoid(gaussians.params[MASK].detach()) <= threshold


SPEC = StageSpec(STAGE, decouple, DecoupleConfig, SCHEMA_VERSION)
