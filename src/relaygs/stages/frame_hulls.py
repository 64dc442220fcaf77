"""Each frame's visual hull of the movers, a geometric target for the deformed foreground: a
copy that spans several frames of motion is drawn to where the movers are at each frame, which
the photometric loss alone cannot do once a copy no longer overlaps its mover's image."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from relaygs.model import GaussianSet
from relaygs.nearest import nearest_indices
from relaygs.stages.carve import BackgroundRenders, frame_hull, hull_bounds, relay_hull_settings
from relaygs.train.views import TrainViews

MAX_HULL_POINTS = 4096  # per frame: enough to cover a mover, few enough for a dense argmin
HULL_POINTS = 3000  # the hull is refined towards this many points (relay's `small` seeds)


@dataclass(frozen=True)
class FrameHulls:
    """Hull points [M_f, 3] of each frame that has any, each hull's voxel size (the distance
    within which a Gaussian counts as inside) and, where carved, the points' colours [M_f, 3]."""

    points: dict[int, Tensor]
    voxel: dict[int, float]
    colours: dict[int, Tensor] = field(default_factory=dict)

    @classmethod
    def carve(
        cls,
        views: TrainViews,
        background: GaussianSet,
        blur: dict[str, Any],
        seed: int,
        relay_keys: Mapping[str, Any] | None = None,
    ) -> FrameHulls:
        """The hulls of every frame with train views, from the residuals of the (frozen)
        `background`'s renders, carved with the relay's `hull_*` keys (`relay_keys`; defaults
        where None); at most MAX_HULL_POINTS a frame, drawn at random."""
        renders = BackgroundRenders(background, **blur)
        bounds = hull_bounds(views.scene.points.xyz)
        settings = relay_hull_settings(relay_keys or {}, HULL_POINTS)
        generator = torch.Generator().manual_seed(seed)
        points, voxel, colours = {}, {}, {}
        for frame in sorted(views.by_frame):
            hull = frame_hull(views, renders, frame, bounds, settings, generator)
            if hull is None or len(hull[0]) == 0:
                continue
            xyz, rgb, voxel[frame] = hull
            if len(xyz) > MAX_HULL_POINTS:
                keep = torch.randperm(len(xyz), generator=generator)[:MAX_HULL_POINTS]
                xyz, rgb = xyz[keep], rgb[keep]
            points[frame], colours[frame] = xyz.to(views.device), rgb.to(views.device)
        return cls(points, voxel, colours)

    def distance(self, means: Tensor, frame: int, coverage: float = 0.0) -> Tensor:
        """Mean distance beyond one voxel from each of `means` [G, 3] to the frame's nearest hull
        point, plus `coverage` times that from each hull point to the nearest mean (0 where the
        frame has no hull or no Gaussians)."""
        hull = self.points.get(frame)
        if hull is None or len(means) == 0:
            return means.new_zeros(())
        tolerance = self.voxel[frame]
        term = distance_beyond(means - hull[nearest_indices(means, hull)], tolerance)
        if coverage > 0.0:
            to_means = nearest_indices(hull, means)
            term = term + coverage * distance_beyond(means[to_means] - hull, tolerance)
        return term


def distance_beyond(offsets: Tensor, tolerance: float) -> Tensor:
    """Mean length of `offsets` [M, 3] beyond `tolerance`; the norm is smoothed by 1e-12 under
    the root, so a zero offset has a zero gradient instead of 0/0."""
    lengths = (offsets.square().sum(dim=1) + 1e-12).sqrt()
    return (lengths - tolerance).clamp_min(0.0).mean()
