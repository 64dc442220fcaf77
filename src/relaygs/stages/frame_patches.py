"""A small patch of Gaussians per frame, shown at that frame alone, seeded where the frame's
visual hull holds movers that the deformed segment copy does not reach: what moves farther
between two frames than its own size (a thrown ball) leaves every copy that spans several
frames, and a patch holds it at the frame where it is (docs/results.md 1k, 1l)."""

from __future__ import annotations

import functools

import torch

from relaygs.data import frame_time
from relaygs.model import GaussianSet
from relaygs.nearest import nearest_indices
from relaygs.stages.carve import hull_seeds
from relaygs.stages.frame_hulls import FrameHulls
from relaygs.train.motion import foreground_means
from relaygs.train.scene_model import GAMMA, SEGMENT, SceneModel

REACH_VOXELS = 2.0  # a hull point farther than this many voxels from every shown mean is missed


@torch.no_grad()
def frame_patches(
    model: SceneModel, hulls: FrameHulls, per_frame: int, opacity: float, seed: int
) -> GaussianSet | None:
    """Seeds for each frame's patch, at most `per_frame` of the hull points that no shown
    Gaussian reaches (drawn at random), with the hull's colour, one voxel's scale and `opacity`;
    placed so that the field moves them onto those points at their frame (one fixed-point
    step), tagged S + frame and with every extra parameter (γ) at zero. None: nothing missed."""
    generator = torch.Generator().manual_seed(seed)
    patches = []
    for frame in sorted(hulls.points):
        hull, colours, voxel = hulls.points[frame], hulls.colours[frame], hulls.voxel[frame]
        missed = _missed(model, hull, frame, REACH_VOXELS * voxel)
        if len(missed) > per_frame:
            missed = missed[torch.randperm(len(missed), generator=generator)[:per_frame]]
        if len(missed):
            canonical = _canonical(model, hull[missed], frame)
            patches.append(_patch(model, canonical, colours[missed], voxel, opacity, frame))
    return functools.reduce(GaussianSet.concat, patches) if patches else None


def _shown_means(model: SceneModel, frame: int) -> torch.Tensor:
    """Where the field puts the foreground rows shown at `frame` (with their own γ)."""
    rows = model.foreground_rows(frame)
    gamma = model.foreground.params.get(GAMMA)
    gamma = None if gamma is None else gamma.detach()[rows]
    xyz = model.foreground.means.detach()[rows]
    return foreground_means(xyz, gamma, model.field, frame_time(frame, model.num_frames))


def _moved(model: SceneModel, xyz: torch.Tensor, frame: int) -> torch.Tensor:
    """Where the field puts new foreground Gaussians (γ = 0) at `xyz` at `frame`."""
    gamma = torch.zeros_like(xyz) if GAMMA in model.foreground.params else None
    return foreground_means(xyz, gamma, model.field, frame_time(frame, model.num_frames))


def _missed(model: SceneModel, hull: torch.Tensor, frame: int, reach: float) -> torch.Tensor:
    """Indices of the hull points farther than `reach` from every mean shown at `frame`."""
    means = _shown_means(model, frame)
    if len(means) == 0:
        return torch.arange(len(hull), device=hull.device)
    nearest = means[nearest_indices(hull, means)]
    return ((hull - nearest).norm(dim=1) > reach).nonzero().squeeze(1)


def _canonical(model: SceneModel, targets: torch.Tensor, frame: int) -> torch.Tensor:
    """Positions the field moves close to `targets` at `frame`: x = t − (f(t) − t)."""
    return 2.0 * targets - _moved(model, targets, frame)


def _patch(
    model: SceneModel,
    xyz: torch.Tensor,
    rgb: torch.Tensor,
    voxel: float,
    opacity: float,
    frame: int,
) -> GaussianSet:
    """Gaussians at `xyz` with the foreground's SH degree, extras at zero, tagged S + frame."""
    foreground = model.foreground
    seeds = hull_seeds(xyz, rgb, foreground.max_sh_degree, opacity, voxel)
    for name in foreground.extra_param_names:
        values = foreground.params[name]
        seeds.add_param(name, values.new_zeros(len(seeds), *values.shape[1:]))
    tag = torch.full((len(seeds),), model.frame_patch_tag(frame), dtype=torch.int32)
    seeds.add_buffer(SEGMENT, tag.to(xyz.device))
    seeds.active_sh_degree = foreground.active_sh_degree
    return seeds
