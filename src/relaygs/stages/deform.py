"""Stage 3, deform: a HexPlane + MLP motion field (4D-GS style) over the upstream Gaussians, each
frame showing its segment's copy; relay, replicate, decouple or warmup upstream (docs/method.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import torch

from relaygs.data import Scene, frame_time
from relaygs.data.effects import COLOR_INCONSISTENCY
from relaygs.field import ColorAffine
from relaygs.field.mlp import MATMUL_DTYPES
from relaygs.model import paper_schedule
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.common import GAUSSIAN_LR, single_upstream, stage_meta, upstream_model
from relaygs.stages.config import PerSetSections, require, require_steps, schedule
from relaygs.stages.frame_hulls import FrameHulls
from relaygs.stages.frame_patches import frame_patches
from relaygs.stages.hull_prefit import prefit_foreground_motion
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.canonical import deform_options_left_out_at_default
from relaygs.train.loop import StepResult, run_training
from relaygs.train.loss import photometric_loss
from relaygs.train.motion import deformed_parts
from relaygs.train.render import Render, splat
from relaygs.train.scene_model import GAMMA, SceneModel, build_field
from relaygs.train.session import ModuleGroup, SetPlan, TrainingSession
from relaygs.train.views import TrainViews, views_per_slot

STAGE = "deform"
SCHEMA_VERSION = 2  # 2: density control ends before the stage's last step
ACCEPTED_UPSTREAM = ("relay", "replicate", "decouple", "warmup")
REGULARISERS = ("plane_smoothness", "time_smoothness", "time_l1")
GRID_LR = {"init": 1.6e-3, "final": 1.6e-4}  # 4D-GS, × scene extent
MLP_LR = {"init": 1.6e-4, "final": 1.6e-5}  # 4D-GS, × scene extent


@dataclass
class DeformConfig(PerSetSections):
    """`cfg["deform"]`: the paper's and 4D-GS's settings; lr_gamma, lr_affine are ours."""

    section: ClassVar[str] = STAGE
    steps: int = 20000
    isolate_fg_bg: bool = True
    background_motion: bool = True
    gamma: bool = True
    frames_per_step: int = 1
    color_affine: str | bool = "auto"
    time_resolution: int | None = None
    multires: tuple[int, ...] = (1, 2)
    spatial_resolution: int = 64
    channels: int = 16
    width: int = 128
    depth: int = 0
    matmul_dtype: str = "float32"
    sh_every: int = 1000
    lr_bg: dict[str, Any] = field(default_factory=lambda: dict(GAUSSIAN_LR))
    lr_fg: dict[str, Any] = field(default_factory=lambda: dict(GAUSSIAN_LR))
    lr_grid: Any = field(default_factory=lambda: dict(GRID_LR))
    lr_mlp: Any = field(default_factory=lambda: dict(MLP_LR))
    lr_gamma: float = 5e-3
    lr_affine: float = 1e-3
    plane_smoothness: float = 2e-4
    time_smoothness: float = 1e-3
    time_l1: float = 1e-4
    hull_weight: float = 0.0
    hull_coverage: float = 0.0
    hull_prefit: int = 0
    frame_patches: int = 0
    patch_opacity: float = 0.5
    densify_bg: dict[str, Any] = field(default_factory=paper_schedule)
    densify_fg: dict[str, Any] = field(default_factory=paper_schedule)

    def validate(self) -> None:
        """Check every value range (errors name `deform.<key>`), once, when the run is planned."""
        require_steps("deform.steps", self.steps)
        require(self.frames_per_step >= 1, "deform.frames_per_step", self.frames_per_step, ">= 1")
        valid = self.color_affine in ("auto", True, False)
        require(valid, "deform.color_affine", self.color_affine, "'auto', true or false")
        resolution = self.time_resolution
        require(resolution is None or resolution >= 1, "deform.time_resolution", resolution, ">= 1")
        multires = list(self.multires)
        valid = len(multires) >= 1 and all(m >= 1 for m in multires)
        require(valid, "deform.multires", multires, "a non-empty list of ints >= 1")
        for key in ("spatial_resolution", "channels", "width"):
            require(getattr(self, key) >= 1, f"deform.{key}", getattr(self, key), "an int >= 1")
        require(self.depth >= 0, "deform.depth", self.depth, "an int >= 0")
        valid = self.matmul_dtype in MATMUL_DTYPES
        require(valid, "deform.matmul_dtype", self.matmul_dtype, f"one of {sorted(MATMUL_DTYPES)}")
        require(self.sh_every >= 0, "deform.sh_every", self.sh_every, "an int >= 0")
        require(self.hull_prefit >= 0, "deform.hull_prefit", self.hull_prefit, "an int >= 0")
        require(self.frame_patches >= 0, "deform.frame_patches", self.frame_patches, "an int >= 0")
        opacity = self.patch_opacity
        require(0.0 < opacity < 1.0, "deform.patch_opacity", opacity, "an opacity in (0, 1)")
        for key in (*REGULARISERS, "lr_gamma", "lr_affine", "hull_weight", "hull_coverage"):
            value = getattr(self, key)
            require(0.0 <= value < math.inf, f"deform.{key}", value, "a finite number >= 0")
        self.plans()
        self.module_schedules()

    def plans(self) -> dict[str, SetPlan]:
        """Training plans of the background and foreground sets (fg lr includes γ)."""
        fg_rates = self.set_rates("fg")
        if self.gamma:
            gamma = schedule(self.lr_gamma, self.steps, f"{STAGE}.lr_gamma")
            fg_rates = replace(fg_rates, extras={**fg_rates.extras, GAMMA: gamma})
        return {
            "bg": SetPlan(self.set_rates("bg"), self.set_densify("bg"), self.sh_every),
            "fg": SetPlan(fg_rates, self.set_densify("fg"), self.sh_every, by_rows=True),
        }

    def module_schedules(self) -> dict[str, Any]:
        """Schedules of the field's grid and MLPs and of the colour affine."""
        return {
            "grid": schedule(self.lr_grid, self.steps, f"{STAGE}.lr_grid"),
            "mlp": schedule(self.lr_mlp, self.steps, f"{STAGE}.lr_mlp"),
            "affine": schedule(self.lr_affine, self.steps, f"{STAGE}.lr_affine"),
        }

    def field_settings(self, scene: Scene) -> dict[str, Any]:
        """DeformationField settings: the grid spans the scene's initial point cloud."""
        xyz = scene.points.xyz
        time_resolution = self.time_resolution or max(2, math.ceil(scene.num_frames / 2))
        return {
            "aabb": [xyz.amin(dim=0).tolist(), xyz.amax(dim=0).tolist()],
            "time_resolution": time_resolution,
            **self.network_settings(),
        }

    def network_settings(self) -> dict[str, Any]:
        """The field's settings that do not depend on a scene: the grid's and the MLPs'."""
        return {
            "isolate_fg_bg": self.isolate_fg_bg,
            "background_motion": self.background_motion,
            "multires": list(self.multires),
            "spatial_resolution": self.spatial_resolution,
            "channels": self.channels,
            "width": self.width,
            "depth": self.depth,
            "matmul_dtype": self.matmul_dtype,
        }


def deform(scene: Scene, upstream: Mapping[str, Artifact], cfg: Mapping[str, Any]) -> Artifact:
    """Train the motion field (and keep refining the Gaussians) over all frames."""
    artifact = single_upstream(upstream, STAGE, ACCEPTED_UPSTREAM)
    section = DeformConfig.from_config(cfg.get(STAGE))
    train = TrainSettings.from_config(cfg.get("train"))
    seed = int(cfg.get("seed", 0))
    device = train.torch_device()
    source = upstream_model(artifact, scene, STAGE)
    model = _starting_model(source, section, scene, seed, train.blur())
    model.to(device)
    views = TrainViews(scene, device)
    camera_index = {camera_id: row for row, camera_id in enumerate(model.affine_cameras)}
    hulls = None  # the hull term's targets (hull_weight > 0)
    wants_hulls = section.hull_weight > 0.0 or section.hull_prefit > 0 or section.frame_patches
    if wants_hulls and len(model.foreground):
        relay_keys = artifact.meta["config"]["section"] if artifact.stage == "relay" else None
        carved = FrameHulls.carve(views, source.background, train.blur(), seed, relay_keys)
        schedules = section.module_schedules()
        prefit_foreground_motion(
            model,
            carved,
            section.hull_prefit,
            {"grid": schedules["grid"].init, "mlp": schedules["mlp"].init},
            {name: getattr(section, name) for name in REGULARISERS},
            section.hull_coverage,
            scene.extent,
            seed,
        )
        hulls = carved if section.hull_weight > 0.0 else None
        if section.frame_patches:
            patches = frame_patches(
                model, carved, section.frame_patches, section.patch_opacity, seed
            )
            if patches is not None:
                model.foreground = model.foreground.concat(patches)
    session = _session(model, section, scene, seed, device)

    def step_fn(step: int) -> StepResult:
        _sync(model, session)
        generator = session.generator
        frames = torch.randint(scene.num_frames, (section.frames_per_step,), generator=generator)
        renders: list[Render] = []
        hull_terms = []
        preds, targets = [], []
        counts = views_per_slot(train.batch_views, section.frames_per_step)
        for frame, count in zip(frames.tolist(), counts, strict=False):  # frames beyond: none
            batch = views.random_views_at(frame, count, generator)
            degree = max(model.background.active_sh_degree, model.foreground.active_sh_degree)
            parts = deformed_parts(
                model.background,
                model.foreground,
                model.foreground_rows(frame),
                model.field,
                frame_time(frame, scene.num_frames),
                degree,
            )
            render = splat(parts, [view.camera for view in batch], degree, **train.blur())
            if hulls is not None:
                outside = hulls.distance(parts[1].means, frame, section.hull_coverage)
                hull_terms.append(outside / scene.extent)
            renders.append(render)
            for view, image in zip(batch, render.images, strict=True):
                if model.affine is not None:
                    image = model.affine(image, camera_index[view.camera.camera_id])
                preds.append(image)
                targets.append(views.image(view))
        loss = photometric_loss(preds, targets, train.ssim_weight)
        regularisers = model.field.regularisers()
        for name in REGULARISERS:
            loss = loss + getattr(section, name) * regularisers[name]
        if hull_terms:
            loss = loss + section.hull_weight * torch.stack(hull_terms).mean()
        return StepResult(loss, renders, preds, targets)

    def counts() -> tuple[int, int]:
        return len(model.background), len(model.foreground)

    report = run_training(STAGE, session, section.steps, train, step_fn, counts)
    _sync(model, session)
    model.to("cpu")
    extra = {"color_affine": model.affine is not None, "upstream_stage": artifact.stage}
    metrics = model.gaussian_counts()
    if section.frame_patches:
        metrics["num_fg_in_frame_patches"] = int(model.in_frame_patches().sum())
    meta = stage_meta(SCHEMA_VERSION, section, train, report, metrics, **extra)
    return model.to_artifact(meta)


def _starting_model(
    source: SceneModel, section: DeformConfig, scene: Scene, seed: int, blur: dict[str, Any]
) -> SceneModel:
    """The upstream model with γ (init 0) on the foreground, the field and the colour affine (a
    decouple foreground, segment 0 with k = T, is one copy shown at every frame), rendered with
    this stage's `blur` (SceneModel's eps2d and antialiased)."""
    foreground = source.foreground
    if section.gamma:
        foreground = foreground.clone()
        foreground.add_param(GAMMA, torch.zeros(len(foreground), 3, device=foreground.means.device))
    settings = section.field_settings(scene)
    model = SceneModel(
        stage=STAGE,
        background=source.background,
        foreground=foreground,
        segments=source.segments,
        **blur,
        field=build_field(settings, seed),
        field_settings=settings,
    )
    affine = section.color_affine  # "auto": on where the scene declares colour inconsistency
    if (COLOR_INCONSISTENCY in scene.effects) if affine == "auto" else affine:
        model.affine_cameras = sorted({v.camera.camera_id for v in scene.train_views})
        model.affine = ColorAffine(len(model.affine_cameras))
    return model


def _session(
    model: SceneModel, section: DeformConfig, scene: Scene, seed: int, device: torch.device
) -> TrainingSession:
    """Gaussian sets (an empty foreground is left out) plus field and affine parameters."""
    plans = section.plans()
    sets = {"bg": model.background}
    if len(model.foreground):
        sets["fg"] = model.foreground
    schedules = section.module_schedules()
    field_groups = model.field.parameter_groups()
    groups = [
        ModuleGroup("grid", field_groups["grid"], schedules["grid"], scale_by_extent=True),
        ModuleGroup("mlp", field_groups["mlp"], schedules["mlp"], scale_by_extent=True),
    ]
    modules = {"field": model.field}
    if model.affine is not None:
        groups.append(ModuleGroup("affine", list(model.affine.parameters()), schedules["affine"]))
        modules["affine"] = model.affine
    return TrainingSession(
        sets=sets,
        plans={name: plans[name] for name in sets},
        extent=scene.extent,
        seed=seed,
        device=device,
        modules=modules,
        module_groups=groups,
    )


def _sync(model: SceneModel, session: TrainingSession) -> None:
    """Point the model at the session's current sets (densification and resume replace them)."""
    model.background = session.sets["bg"]
    if "fg" in session.sets:
        model.foreground = session.sets["fg"]


SPEC = StageSpec(
    STAGE,
    deform,
    DeformConfig,
    SCHEMA_VERSION,
    ACCEPTED_UPSTREAM,
    deform_options_left_out_at_default,
)
