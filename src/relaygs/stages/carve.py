"""Where the movers are at a frame: the visual hull of what the frozen background render misses
in (nearly) every train camera, coarse voxels then sub-voxels (docs/method.md, Carved copies)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from relaygs.data import Camera
from relaygs.errors import InputError
from relaygs.model import GaussianSet
from relaygs.train.render import FrozenRenders, part_of
from relaygs.train.views import TrainViews

SUBDIVISIONS = 4  # sub-voxels per axis of a kept coarse voxel (first pass)
MAX_SUBDIVISIONS = 16  # a finer pass resolves movers that a few coarse voxels hold
MAX_FINE_CANDIDATES = 1 << 18  # sub-voxels a finer pass may test (cost: each meets every camera)
# coarse voxels refined at most: a mover fills a few hundred, more mean no silhouette (an
# unconverged background) and would cost seconds per frame for seeds thinned anyway
MAX_REFINED_VOXELS = 4096
MIN_CAMERAS = 3  # a point seen by fewer train cameras cannot be triangulated


@dataclass(frozen=True)
class HullSettings:
    """Residual threshold, coarse voxels along the longest axis, tolerated miss fraction, the
    fraction of a frame's cameras that must see a point, and the hull points wanted (None: one
    pass at SUBDIVISIONS)."""

    residual: float = 0.15
    coarse_voxels: int = 48
    misses: float = 0.15
    seen: float = 0.5
    target_points: int | None = None

    def cameras_needed(self, cameras: int) -> int:
        """Cameras that must see a point of the hull: `seen` of them, and MIN_CAMERAS at least
        (a region only a few cameras see, at a rig's edge, is a wide cone, not a mover)."""
        return max(MIN_CAMERAS, math.ceil(self.seen * cameras))


def relay_hull_settings(keys: Mapping[str, Any], target_points: int | None) -> HullSettings:
    """HullSettings from the relay section's `hull_*` keys (a RelayConfig's fields or the
    config echo of a relay artifact); keys it lacks keep their defaults."""
    defaults = HullSettings()
    return HullSettings(
        residual=float(keys.get("hull_residual", defaults.residual)),
        coarse_voxels=int(keys.get("hull_voxels", defaults.coarse_voxels)),
        misses=float(keys.get("hull_misses", defaults.misses)),
        seen=float(keys.get("hull_seen", defaults.seen)),
        target_points=target_points,
    )


def hull_bounds(cloud: Tensor) -> Tensor:
    """[2, 3] box of the scene's points padded by 5 % on every side: where hulls are carved."""
    lower, upper = cloud.min(dim=0).values, cloud.max(dim=0).values
    pad = 0.05 * (upper - lower).clamp_min(1e-3)
    return torch.stack([lower - pad, upper + pad])


class BackgroundRenders:
    """Renders of a static background, one per camera (cached: see FrozenRenders)."""

    def __init__(self, background: GaussianSet, eps2d: float, antialiased: bool = False) -> None:
        self.background = background
        self._renders = FrozenRenders(eps2d, antialiased)

    def images(self, cameras: list[Camera]) -> Tensor:
        """[C,H,W,3] renders clamped to [0, 1], on the CPU, in the order of `cameras`."""
        degree = self.background.active_sh_degree
        part = part_of("bg", self.background, degree, frozen=True)
        return self._renders.layer([part], cameras, degree).colors.cpu().clamp(0.0, 1.0)


def frame_hull(
    views: TrainViews,
    renders: BackgroundRenders,
    frame: int,
    bounds: Tensor,
    settings: HullSettings,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor, float] | None:
    """Hull points, colours, voxel size of the background's misses at `frame` (None: no view)."""
    frame_views = views.by_frame.get(frame, [])
    if not frame_views:
        return None
    cameras = [view.camera for view in frame_views]
    images = torch.stack([views.scene.image(view) for view in frame_views])
    masks = residual_masks(renders.images(cameras), images, settings.residual)
    return visual_hull(masks, images, cameras, bounds, settings, generator)


def hull_seeds(
    xyz: Tensor, rgb: Tensor, max_sh_degree: int, opacity: float, voxel: float
) -> GaussianSet:
    """Gaussians at hull points `xyz` with their colours `rgb` (clamped to [0, 1]), each one
    voxel in size: the hull is a regular grid, and a stray point far from the others would
    otherwise get a huge nearest-neighbour scale and haze the view."""
    seeds = GaussianSet.from_points(xyz, rgb.clamp(0.0, 1.0), max_sh_degree, opacity)
    seeds.params["log_scales"].fill_(math.log(voxel))
    return seeds


def residual_masks(renders: Tensor, images: Tensor, threshold: float) -> Tensor:
    """[C,H,W] bool: pixels the background render misses by more than `threshold` in a channel,
    after a least-squares gain per camera and channel (a camera's own colour response)."""
    numerator = (renders * images).sum(dim=(1, 2))
    denominator = (renders * renders).sum(dim=(1, 2))
    safe = torch.where(denominator > 1e-8, denominator, torch.ones_like(denominator))
    gains = torch.where(denominator > 1e-8, numerator / safe, torch.ones_like(numerator))
    residual = (images - renders * gains[:, None, None, :]).abs().amax(dim=-1)
    return residual > threshold


def visual_hull(
    masks: Tensor,
    images: Tensor,
    cameras: list[Camera],
    bounds: Tensor,
    settings: HullSettings,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor, float]:
    """Points [M,3] in the hull of `masks` within `bounds`, their mean colours and the fine voxel
    size; beyond MAX_REFINED_VOXELS coarse voxels a random subset is refined. A first pass that
    keeps fewer than `settings.target_points` is redone on finer sub-voxels of the coarse voxels
    it kept any in, so small movers in a large scene get as many (and as small) seeds as large
    ones."""
    if masks.shape[0] != len(cameras) or images.shape[:3] != masks.shape:
        raise InputError(f"visual_hull: {len(cameras)} cameras, masks {tuple(masks.shape)}")
    lower, upper = bounds[0], bounds[1]
    size = float((upper - lower).max()) / settings.coarse_voxels
    if not size > 0:
        raise InputError(f"visual_hull: empty bounds {bounds.tolist()}")
    counts = ((upper - lower) / size).ceil().clamp_min(1).long()
    axes = [lower[i] + size * (torch.arange(int(counts[i])) + 0.5) for i in range(3)]
    coarse = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    dilated = F.max_pool2d(masks[:, None].float(), 5, stride=1, padding=2)[:, 0] > 0
    coarse = coarse[_consistent(coarse, dilated, cameras, settings)[0]]
    if len(coarse) > MAX_REFINED_VOXELS:
        pick = torch.randperm(len(coarse), generator=generator)[:MAX_REFINED_VOXELS]
        coarse = coarse[pick.sort().values]
    hull, occupied = _refined(coarse, size, SUBDIVISIONS, masks, images, cameras, settings)
    # only the coarse voxels that kept a sub-voxel hold the mover: the dilated pass keeps more
    coarse = coarse[occupied]
    finer = finer_subdivisions(len(hull[0]), settings.target_points, len(coarse))
    if finer > SUBDIVISIONS:
        hull = _refined(coarse, size, finer, masks, images, cameras, settings)[0]
    return hull


def finer_subdivisions(kept: int, wanted: int | None, coarse: int) -> int:
    """Sub-voxels per axis that should keep about `wanted` points, given that SUBDIVISIONS kept
    `kept` in `coarse` voxels (points grow with the cube); bounded by MAX_SUBDIVISIONS and by
    MAX_FINE_CANDIDATES sub-voxels in all."""
    if wanted is None or kept == 0 or kept >= wanted:
        return SUBDIVISIONS
    wished = math.ceil(SUBDIVISIONS * (wanted / kept) ** (1.0 / 3.0))
    affordable = int((MAX_FINE_CANDIDATES / max(coarse, 1)) ** (1.0 / 3.0))
    return max(SUBDIVISIONS, min(wished, MAX_SUBDIVISIONS, affordable))


def _refined(
    coarse: Tensor,
    size: float,
    subdivisions: int,
    masks: Tensor,
    images: Tensor,
    cameras: list[Camera],
    settings: HullSettings,
) -> tuple[tuple[Tensor, Tensor, float], Tensor]:
    """The sub-voxel centres of `coarse` voxels (edge `size`, `subdivisions`³ each) that the
    masks keep, their mean colours and the sub-voxel size; and which coarse voxels kept any."""
    fine_size = size / subdivisions
    steps = (torch.arange(subdivisions) + 0.5) * fine_size - size / 2
    offsets = torch.stack(torch.meshgrid(steps, steps, steps, indexing="ij"), dim=-1)
    fine = (coarse[:, None, :] + offsets.reshape(1, -1, 3)).reshape(-1, 3)
    keep, colors = _consistent(fine, masks, cameras, settings, images)
    occupied = keep.reshape(len(coarse), subdivisions**3).any(dim=1)
    return (fine[keep], colors[keep], fine_size), occupied


def _consistent(
    points: Tensor,
    masks: Tensor,
    cameras: list[Camera],
    settings: HullSettings,
    images: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Which points fall in the mask of all but a `misses` fraction of the cameras that see
    them (`cameras_needed` at least), and the mean colour of `images` where they hit. A point
    that can no longer pass (too many misses, or too few cameras left to see it) is dropped
    from the later cameras' tests: the same points are kept, most of the grid after a few."""
    n = points.shape[0]
    needed = settings.cameras_needed(len(cameras))
    seen = torch.zeros(n, dtype=torch.int64)
    hits = torch.zeros(n, dtype=torch.int64)
    color_sum = torch.zeros(n, 3)
    active = torch.arange(n)
    for index, camera in enumerate(cameras):
        left = len(cameras) - index
        active = active[_passable(seen[active], hits[active], left, needed, settings.misses)]
        # deeper than 1e-3 at the default near plane
        pixels, inside = camera.project(points[active], min_depth=0.1 * camera.near)
        column, row = pixels[:, 0].floor().long(), pixels[:, 1].floor().long()
        column = column.clamp(0, camera.width - 1)
        row = row.clamp(0, camera.height - 1)
        hit = inside & masks[index][row, column]
        seen[active] += inside.long()
        hits[active] += hit.long()
        if images is not None:
            color_sum[active] += images[index][row, column] * hit[:, None].float()
    keep = _passable(seen, hits, 0, needed, settings.misses)
    colors = color_sum / hits.clamp_min(1)[:, None].float()
    return keep, colors


def _passable(seen: Tensor, hits: Tensor, left: int, needed: int, misses: float) -> Tensor:
    """Whether a point with these counts is kept if each of `left` further cameras sees and hits
    it: seen by `needed`, missing at most a `misses` fraction of those that see it (with no
    cameras left, the keep test itself)."""
    most_seen = seen + left
    allowed = (misses * most_seen.float()).floor().long()
    return (most_seen >= needed) & (seen - hits <= allowed)
