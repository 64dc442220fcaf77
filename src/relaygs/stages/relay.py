"""Stage 2, relay: S = ceil(T/k) copies of the decoupled foreground, each seeded from the visual
hull of its segment's movers and fitted to the segment's pseudo-views (docs/method.md)."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch

from relaygs.data import Scene
from relaygs.model import GaussianSet, paper_schedule
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.carve import (
    BackgroundRenders,
    frame_hull,
    hull_bounds,
    hull_seeds,
    relay_hull_settings,
)
from relaygs.stages.common import (
    BACKGROUND_LR,
    FOREGROUND_LR,
    single_upstream,
    stage_meta,
    training_scene,
    upstream_model,
)
from relaygs.stages.config import PerSetSections, require, require_steps
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.canonical import uniform_unless_adaptive
from relaygs.train.loop import StepResult, TrainReport, run_training
from relaygs.train.loss import photometric_loss
from relaygs.train.render import FrozenRenders, part_of, slot_mask, splat
from relaygs.train.scene_model import (
    SEGMENT,
    SceneModel,
    core_only,
    foreground_with_segments,
    replicate_foreground,
)
from relaygs.train.segment_plan import SegmentPlan, boundaries_fixed, frame_motion
from relaygs.train.segments import SegmentTargets, pseudo_frames
from relaygs.train.session import SetPlan, TrainingSession
from relaygs.train.views import TrainViews, views_per_slot

STAGE = "relay"
SEGMENT_MODES = ("uniform", "adaptive")
SEED_MODES = ("replicate", "carve")
SCHEMA_VERSION = 3  # 2: density control ends before the last step; 3: hulls refined to seed_points
ACCEPTED_UPSTREAM = ("decouple",)


@dataclass
class RelayConfig(PerSetSections):
    """`cfg["relay"]`: the paper's foreground rates and density control for the copies; `lr_bg`,
    `densify_bg` only matter with `freeze_background: false`."""

    section: ClassVar[str] = STAGE
    steps: int = 14000
    k: int = 16
    segments: str = "uniform"
    pseudo_views: bool = True
    p: int = 3
    segments_per_step: int = 1
    freeze_background: bool = True
    seed_copies: str = "carve"
    hull_residual: float = 0.15
    hull_voxels: int = 48
    hull_misses: float = 0.15
    hull_seen: float = 0.5
    seed_points: int = 1500
    seed_opacity: float = 0.1
    sh_every: int = 1000
    lr_fg: dict[str, Any] = field(default_factory=lambda: dict(FOREGROUND_LR))
    lr_bg: dict[str, Any] = field(default_factory=lambda: dict(BACKGROUND_LR))
    densify_fg: dict[str, Any] = field(default_factory=paper_schedule)
    densify_bg: dict[str, Any] = field(default_factory=paper_schedule)

    def validate(self) -> None:
        """Check every value range (errors name `relay.<key>`), once, when the run is planned."""
        require_steps("relay.steps", self.steps)
        require(self.k >= 1, "relay.k", self.k, "an int >= 1")
        modes = list(SEGMENT_MODES)
        require(self.segments in modes, "relay.segments", self.segments, f"one of {modes}")
        require(self.p >= 1, "relay.p", self.p, "an int >= 1")
        per_step = self.segments_per_step
        require(per_step >= 1, "relay.segments_per_step", per_step, "an int >= 1")
        require(self.sh_every >= 0, "relay.sh_every", self.sh_every, "an int >= 0")
        mode = self.seed_copies
        require(mode in SEED_MODES, "relay.seed_copies", mode, f"one of {list(SEED_MODES)}")
        require(0.0 < self.hull_residual < 1.0, "relay.hull_residual", self.hull_residual, "(0, 1)")
        require(self.hull_voxels >= 1, "relay.hull_voxels", self.hull_voxels, "an int >= 1")
        require(0.0 <= self.hull_misses < 1.0, "relay.hull_misses", self.hull_misses, "[0, 1)")
        require(0.0 <= self.hull_seen <= 1.0, "relay.hull_seen", self.hull_seen, "[0, 1]")
        require(self.seed_points >= 1, "relay.seed_points", self.seed_points, "an int >= 1")
        opacity = self.seed_opacity
        require(0.0 < opacity < 1.0, "relay.seed_opacity", opacity, "an opacity in (0, 1)")
        for name in ("fg", "bg"):  # bg too: it enters the key even while the background is frozen
            self.set_rates(name)
            self.set_densify(name)

    def plans(self) -> dict[str, SetPlan]:
        """Training plan of the foreground copies and (when trained) the background."""
        fg = SetPlan(self.set_rates("fg"), self.set_densify("fg"), self.sh_every, by_rows=True)
        plans = {"fg": fg}
        if not self.freeze_background:
            plans["bg"] = SetPlan(self.set_rates("bg"), self.set_densify("bg"), self.sh_every)
        return plans


def relay(scene: Scene, upstream: Mapping[str, Artifact], cfg: Mapping[str, Any]) -> Artifact:
    """Replicate the decouple foreground into per-segment copies and fit each to its segment."""
    artifact = single_upstream(upstream, STAGE, ACCEPTED_UPSTREAM)
    section = RelayConfig.from_config(cfg.get(STAGE))
    train = TrainSettings.from_config(cfg.get("train"))
    seed = int(cfg.get("seed", 0))
    device = train.torch_device()
    source = upstream_model(artifact, scene, STAGE).to(device)
    training = training_scene(scene, train, early_stage=True)
    segments = SegmentPlan.uniform(training.num_frames, section.k)  # or as many placed by motion
    if section.segments != "uniform" and not boundaries_fixed(training.num_frames, section.k):
        segments = SegmentPlan.by_motion(frame_motion(training), segments.count)
    views = TrainViews(training, device)
    if section.seed_copies == "carve":
        replica = core_only(source.foreground)
        renders = BackgroundRenders(source.background, **train.blur())
        copies = carved_copies(views, renders, replica, section, segments, seed)
    else:
        copies = replicate_foreground(source.foreground, segments.count).to(device)
    sets = {"fg": copies} if len(copies) else {}
    if not section.freeze_background:
        sets["bg"] = source.background
    report = None
    if sets:  # nothing to train without foreground when the background is frozen
        sets, report = _train(training, views, source, sets, segments, section, train, seed)
    model = SceneModel(
        stage=STAGE,
        background=sets.get("bg", source.background),
        foreground=sets.get("fg", copies),
        segments=segments,
        **train.blur(),
    ).to("cpu")
    per_segment = torch.bincount(
        model.foreground.buffers[SEGMENT].long(), minlength=model.num_segments
    )
    metrics = {
        **model.gaussian_counts(),
        "fg_per_segment": per_segment.tolist(),
        "segment_lengths": model.segments.lengths(),
    }
    meta = stage_meta(SCHEMA_VERSION, section, train, report, metrics, downscale=training.downscale)
    return model.to_artifact(meta)


def _train(
    scene: Scene,
    views: TrainViews,
    source: SceneModel,
    sets: dict[str, GaussianSet],
    segments: SegmentPlan,
    section: RelayConfig,
    train: TrainSettings,
    seed: int,
) -> tuple[dict[str, GaussianSet], TrainReport]:
    """Fit copy s (and a trainable background) to segment s's targets."""
    plans = section.plans()
    session = TrainingSession(
        sets=sets,
        plans={name: plans[name] for name in sets},
        extent=scene.extent,
        seed=seed,
        device=views.device,
    )
    targets = SegmentTargets(views, segments, section.p, section.pseudo_views)
    empty = source.foreground.subset(torch.zeros(0, dtype=torch.int64))
    # A frozen background looks the same at every step: render it once per camera.
    frozen = FrozenRenders(**train.blur()) if section.freeze_background else None

    def current() -> tuple[GaussianSet, GaussianSet]:
        return session.sets.get("bg", source.background), session.sets.get("fg", empty)

    def step_fn(step: int) -> StepResult:
        generator = session.generator
        background, foreground = current()
        degree = max(background.active_sh_degree, foreground.active_sh_degree)
        cameras, goals, slots = [], [], []
        for count in views_per_slot(train.batch_views, section.segments_per_step):
            segment = int(torch.randint(segments.count, (1,), generator=generator))
            batch = views.random_views_at(segments.frames(segment)[0], count, generator)
            goals += [targets.target(view.camera.camera_id, segment, generator) for view in batch]
            cameras += [view.camera for view in batch]
            slots.append((len(batch), (foreground.buffers[SEGMENT] == segment).nonzero()[:, 0]))
        # one render of every drawn copy, each camera masked to its own segment's copy
        shown = part_of("fg", foreground, degree, rows=torch.cat([rows for _, rows in slots]))
        background_part = part_of("bg", background, degree, frozen=section.freeze_background)
        mask = None
        if len(slots) > 1:
            mask = slot_mask(background_part.count, [(n, len(r)) for n, r in slots])
        parts = [background_part, shown]
        render = splat(parts, cameras, degree, frozen, mask, **train.blur())
        loss = photometric_loss(render.images, goals, train.ssim_weight)
        return StepResult(loss, [render], render.images, goals)

    def counts() -> tuple[int, int]:
        background, foreground = current()
        return len(background), len(foreground)

    report = run_training(STAGE, session, section.steps, train, step_fn, counts)
    return session.sets, report


@torch.no_grad()
def carved_copies(
    views: TrainViews,
    renders: BackgroundRenders,
    replica: GaussianSet,
    section: RelayConfig,
    segments: SegmentPlan,
    seed: int,
) -> GaussianSet:
    """One copy per segment, on the replica's device, from the hull at its pseudo frames (thinned
    to `seed_points` at random); a segment whose hull is empty keeps the replica."""
    bounds = hull_bounds(views.scene.points.xyz)
    settings = relay_hull_settings(vars(section), section.seed_points)
    generator = torch.Generator().manual_seed(seed)
    copies = []
    for segment in range(segments.count):
        frames = pseudo_frames(segments.frames(segment), section.p)
        hulls = [frame_hull(views, renders, frame, bounds, settings, generator) for frame in frames]
        hulls = [hull for hull in hulls if hull is not None]
        xyz = torch.cat([points for points, _, _ in hulls]) if hulls else torch.zeros(0, 3)
        if len(xyz) == 0:
            copies.append(_tagged(replica, segment))
            continue
        rgb = torch.cat([colors for _, colors, _ in hulls])
        if len(xyz) > section.seed_points:
            keep = torch.randperm(len(xyz), generator=generator)[: section.seed_points]
            xyz, rgb = xyz[keep], rgb[keep]
        seeds = hull_seeds(xyz, rgb, replica.max_sh_degree, section.seed_opacity, hulls[0][2])
        copies.append(_tagged(seeds.to(replica.means.device), segment))
    return functools.reduce(GaussianSet.concat, copies)


def _tagged(gaussians: GaussianSet, segment: int) -> GaussianSet:
    """`gaussians` (core only: a replica or seeds) with every row tagged as `segment`."""
    tags = torch.full((len(gaussians),), segment, dtype=torch.int32)
    return foreground_with_segments(gaussians, tags)


SPEC = StageSpec(
    STAGE, relay, RelayConfig, SCHEMA_VERSION, ACCEPTED_UPSTREAM, uniform_unless_adaptive
)
