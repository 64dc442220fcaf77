"""Starting copies of the relay stage: the frame-0 foreground replicated (the paper), or each
segment's copy seeded from the visual hull of the background's residuals at the segment's
pseudo frames (for movers that travel further in a segment than their own size)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from relaygs.model import GaussianSet
from relaygs.stages.carve import residual_masks, visual_hull
from relaygs.stages.render import part_of, splat
from relaygs.stages.scene_model import foreground_with_segments
from relaygs.stages.segments import pseudo_frames
from relaygs.stages.views import TrainViews

if TYPE_CHECKING:
    from relaygs.stages.relay import RelayConfig

SEED_MODES = ("replicate", "carve")


@torch.no_grad()
def carved_copies(
    views: TrainViews,
    background: GaussianSet,
    replica: GaussianSet,
    section: RelayConfig,
    seed: int,
) -> GaussianSet:
    """One copy per segment from the hull at its pseudo frames (at most `section.seed_points`
    Gaussians, randomly thinned); a segment whose hull is empty keeps the replica."""
    scene = views.scene
    k, settings = section.k, section.hull()
    segments = -(-scene.num_frames // k)
    bounds = _bounds(scene.points.xyz)
    generator = torch.Generator().manual_seed(seed)
    copies = []
    voxel = 1.0
    for segment in range(segments):
        points, colors = [], []
        for frame in pseudo_frames(segment, k, scene.num_frames, section.p):
            frame_views = views.by_frame.get(frame, [])
            if not frame_views:
                continue
            cameras = [view.camera for view in frame_views]
            degree = background.active_sh_degree
            renders = splat([part_of("bg", background, degree, frozen=True)], cameras, degree)
            rendered = torch.stack(renders.images).cpu().clamp(0.0, 1.0)
            images = torch.stack([scene.image(view) for view in frame_views])
            masks = residual_masks(rendered, images, settings.residual)
            frame_points, frame_colors, voxel = visual_hull(
                masks, images, cameras, bounds, settings
            )
            points.append(frame_points)
            colors.append(frame_colors)
        xyz = torch.cat(points) if points else torch.zeros(0, 3)
        if len(xyz) == 0:
            copies.append(_tagged(replica, segment))
            continue
        rgb = torch.cat(colors)
        if len(xyz) > section.seed_points:
            keep = torch.randperm(len(xyz), generator=generator)[: section.seed_points]
            xyz, rgb = xyz[keep], rgb[keep]
        fresh = GaussianSet.from_points(
            xyz, rgb.clamp(0.0, 1.0), replica.max_sh_degree, section.seed_opacity
        )
        # the hull is a regular grid: one voxel is each seed's size (a stray hull point far
        # from the others would otherwise get a huge nearest-neighbour scale and haze the view)
        fresh.params["log_scales"].fill_(math.log(voxel))
        copies.append(_tagged(fresh, segment))
    stacked = copies[0]
    for copy in copies[1:]:
        stacked = stacked.concat(copy)
    return stacked


def _tagged(gaussians: GaussianSet, segment: int) -> GaussianSet:
    """`gaussians` (core parameters) with every row tagged as `segment`."""
    core = {k: v for k, v in gaussians.to_tensors().items() if not k.startswith("buffer.")}
    plain = GaussianSet.from_tensors(core)
    return foreground_with_segments(plain, torch.full((len(plain),), segment, dtype=torch.int32))


def _bounds(xyz: Tensor) -> Tensor:
    """[2,3] bounds of the scene's point cloud, padded by 5 % on every side."""
    lower, upper = xyz.min(dim=0).values, xyz.max(dim=0).values
    pad = 0.05 * (upper - lower).clamp_min(1e-3)
    return torch.stack([lower - pad, upper + pad])
