"""The 4D-GS baseline's coarse stage: one static 3DGS fitted to every frame, all background."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch

from relaygs.data import Scene
from relaygs.model import BACKGROUND_DENSIFY, DensifySettings, SetLearningRates, paper_schedule
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.common import GAUSSIAN_LR, no_upstream, stage_meta, training_scene
from relaygs.stages.config import Section, densify_settings, learning_rates, require_steps
from relaygs.stages.decouple import check_static_settings
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.initial import static_session
from relaygs.train.loop import StepResult, run_training
from relaygs.train.loss import photometric_loss
from relaygs.train.render import part_of, splat
from relaygs.train.scene_model import SceneModel, foreground_with_segments
from relaygs.train.segment_plan import SegmentPlan
from relaygs.train.session import SetPlan
from relaygs.train.views import TrainViews

STAGE = "warmup"
SCHEMA_VERSION = 2  # 2: density control ends before the stage's last step
SET = "bg"


@dataclass
class WarmupConfig(Section):
    """`cfg["warmup"]`: 4D-GS's coarse stage, 3DGS rates and density control (docs/method.md)."""

    section: ClassVar[str] = STAGE
    steps: int = 3000
    init_points: int | None = None
    init_opacity: float = 0.1
    sh_degree: int = 3
    sh_every: int = 1000
    lr: dict[str, Any] = field(default_factory=lambda: dict(GAUSSIAN_LR))
    densify: dict[str, Any] = field(default_factory=paper_schedule)

    def validate(self) -> None:
        """Check every value range (errors name `warmup.<key>`), once, when the run is planned."""
        require_steps("warmup.steps", self.steps)
        check_static_settings(self, STAGE)
        self.learning_rates()
        self.densify_settings()

    def learning_rates(self) -> SetLearningRates:
        return learning_rates(self.lr, self.steps, f"{STAGE}.lr")

    def densify_settings(self) -> DensifySettings:
        return densify_settings(self.densify, BACKGROUND_DENSIFY, f"{STAGE}.densify", self.steps)


def warmup(scene: Scene, upstream: Mapping[str, Artifact], cfg: Mapping[str, Any]) -> Artifact:
    """Fit one static Gaussian set to views drawn over all frames and train cameras."""
    no_upstream(upstream, STAGE)
    section = WarmupConfig.from_config(cfg.get(STAGE))
    train = TrainSettings.from_config(cfg.get("train"))
    seed = int(cfg.get("seed", 0))
    device = train.torch_device()
    training = training_scene(scene, train, early_stage=False)
    plan = SetPlan(section.learning_rates(), section.densify_settings(), section.sh_every)
    session = static_session(SET, scene, section, plan, seed, device)
    views = TrainViews(training, device)

    def step_fn(step: int) -> StepResult:
        batch = views.random_views(train.batch_views, session.generator)
        gaussians = session.sets[SET]
        degree = gaussians.active_sh_degree
        cameras = [view.camera for view in batch]
        part = part_of(SET, gaussians, degree)
        render = splat([part], cameras, degree, **train.blur())
        targets = [views.image(view) for view in batch]
        loss = photometric_loss(render.images, targets, train.ssim_weight)
        return StepResult(loss, [render], render.images, targets)

    def counts() -> tuple[int, int]:
        return len(session.sets[SET]), 0

    report = run_training(STAGE, session, section.steps, train, step_fn, counts)
    background = session.sets[SET].to("cpu")
    empty = background.subset(torch.zeros(len(background), dtype=torch.bool))
    model = SceneModel(
        stage=STAGE,
        background=background,
        foreground=foreground_with_segments(empty, torch.zeros(0, dtype=torch.int32)),
        segments=SegmentPlan.uniform(scene.num_frames, scene.num_frames),
        **train.blur(),
    )
    metrics = model.gaussian_counts()
    meta = stage_meta(SCHEMA_VERSION, section, train, report, metrics, downscale=training.downscale)
    return model.to_artifact(meta)


SPEC = StageSpec(STAGE, warmup, WarmupConfig, SCHEMA_VERSION)
