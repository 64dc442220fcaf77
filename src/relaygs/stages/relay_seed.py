"""The relay stage's carved starting copies: each segment's seeded from the visual hull of the
background's residuals at its pseudo frames (movers that travel further than their size)."""

from __future__ import annotations

import math
from typing import Protocol

import torch
from torch import Tensor

from relaygs.data import Camera
from relaygs.model import GaussianSet
from relaygs.stages.carve import HullSettings, residual_masks, visual_hull
from relaygs.train.render import FrozenRenders, part_of
from relaygs.train.scene_model import foreground_with_segments
from relaygs.train.segment_plan import SegmentPlan
from relaygs.train.segments import pseudo_frames
from relaygs.train.views import TrainViews

SEED_MODES = ("replicate", "carve")


class SeedSettings(Protocol):
    """What seeding reads of `RelayConfig` (declared here: the stage imports this module)."""

    @property
    def p(self) -> int: ...
    @property
    def seed_points(self) -> int: ...
    @property
    def seed_opacity(self) -> float: ...
    def hull(self) -> HullSettings: ...


@torch.no_grad()
def carved_copies(
    views: TrainViews,
    background: GaussianSet,
    replica: GaussianSet,
    section: SeedSettings,
    segments: SegmentPlan,
    seed: int,
) -> GaussianSet:
    """One copy per segment, on the replica's device, from the hull at its pseudo frames (thinned
    to `seed_points` at random); a segment whose hull is empty keeps the replica."""
    scene = views.scene
    bounds = _bounds(scene.points.xyz)
    generator = torch.Generator().manual_seed(seed)
    renders = BackgroundRenders(background)
    copies = []
    for segment in range(segments.count):
        frames = pseudo_frames(segments.frames(segment), section.p)
        hulls = [_hull_at(views, renders, frame, bounds, section, generator) for frame in frames]
        hulls = [hull for hull in hulls if hull is not None]
        xyz = torch.cat([points for points, _, _ in hulls]) if hulls else torch.zeros(0, 3)
        if len(xyz) == 0:
            copies.append(_tagged(replica, segment))
            continue
        rgb = torch.cat([colors for _, colors, _ in hulls])
        if len(xyz) > section.seed_points:
            keep = torch.randperm(len(xyz), generator=generator)[: section.seed_points]
            xyz, rgb = xyz[keep], rgb[keep]
        seeds = GaussianSet.from_points(
            xyz, rgb.clamp(0.0, 1.0), replica.max_sh_degree, section.seed_opacity
        ).to(replica.means.device)
        # the hull is a regular grid: one voxel is each seed's size (a stray hull point far
        # from the others would otherwise get a huge nearest-neighbour scale and haze the view)
        seeds.params["log_scales"].fill_(math.log(hulls[0][2]))
        copies.append(_tagged(seeds, segment))
    stacked = copies[0]
    for copy in copies[1:]:
        stacked = stacked.concat(copy)
    return stacked


class BackgroundRenders:
    """Renders of a static background, one per camera (cached: see FrozenRenders)."""

    def __init__(self, background: GaussianSet) -> None:
        """Renders of `background` at its active SH degree, made on first request."""
        self.background = background
        self._renders = FrozenRenders()

    def images(self, cameras: list[Camera]) -> Tensor:
        """[C,H,W,3] renders clamped to [0, 1], on the CPU, in the order of `cameras`."""
        degree = self.background.active_sh_degree
        part = part_of("bg", self.background, degree, frozen=True)
        return self._renders.layer([part], cameras, degree).colors.cpu().clamp(0.0, 1.0)


def _hull_at(
    views: TrainViews,
    renders: BackgroundRenders,
    frame: int,
    bounds: Tensor,
    section: SeedSettings,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor, float] | None:
    """Hull points, colours and voxel size of what the background misses at `frame` (None when
    the frame has no train view)."""
    frame_views = views.by_frame.get(frame, [])
    if not frame_views:
        return None
    cameras = [view.camera for view in frame_views]
    images = torch.stack([views.scene.image(view) for view in frame_views])
    settings = section.hull()
    masks = residual_masks(renders.images(cameras), images, settings.residual)
    return visual_hull(masks, images, cameras, bounds, settings, generator)


def _tagged(gaussians: GaussianSet, segment: int) -> GaussianSet:
    """`gaussians` with its buffers dropped and every row tagged as `segment`."""
    core = {k: v for k, v in gaussians.to_tensors().items() if not k.startswith("buffer.")}
    plain = GaussianSet.from_tensors(core)
    return foreground_with_segments(plain, torch.full((len(plain),), segment, dtype=torch.int32))


def _bounds(xyz: Tensor) -> Tensor:
    """[2,3] bounds of the scene's point cloud, padded by 5 % on every side."""
    lower, upper = xyz.min(dim=0).values, xyz.max(dim=0).values
    pad = 0.05 * (upper - lower).clamp_min(1e-3)
    return torch.stack([lower - pad, upper + pad])
