"""Segments of k consecutive frames and the relay stage's per-segment targets (pseudo-views)."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from relaygs.errors import InputError
from relaygs.train.views import TrainViews


def num_segments(num_frames: int, k: int) -> int:
    """S = ceil(T / k)."""
    return math.ceil(num_frames / k)


def segment_frames(segment: int, k: int, num_frames: int) -> range:
    """The frames of segment s: [s·k, min((s+1)·k, T))."""
    return range(segment * k, min((segment + 1) * k, num_frames))


def pseudo_frames(segment: int, k: int, num_frames: int, p: int) -> list[int]:
    """p frames spread uniformly over the segment (first, …, last; p = 3 adds the middle);
    fewer when the segment is shorter; p = 1 takes the middle frame."""
    frames = segment_frames(segment, k, num_frames)
    first, last = frames[0], frames[-1]
    if p == 1:
        return [(first + last) // 2]
    spread = np.rint(np.linspace(first, last, p)).astype(int)
    return sorted({int(frame) for frame in spread})


class SegmentTargets:
    """Training targets for (camera, segment): the pseudo-view (mean image of the segment's
    pseudo frames, cached) or, without pseudo-views, the image at one random frame."""

    def __init__(self, views: TrainViews, k: int, p: int, pseudo_views: bool) -> None:
        """Targets over the scene of `views` with segment length `k` and `p` blended frames."""
        self.views = views
        self.k = k
        self.p = p
        self.pseudo_views = pseudo_views
        self.num_frames = views.scene.num_frames
        self._cache: dict[tuple[int, int], Tensor] = {}

    def target(self, camera_id: int, segment: int, generator: torch.Generator) -> Tensor:
        """The [H,W,3] target of `camera_id` for `segment`."""
        if self.pseudo_views:
            key = (camera_id, segment)
            if key not in self._cache:
                self._cache[key] = self.pseudo_view(camera_id, segment)
            return self._cache[key]
        frames = self._frames_with(camera_id, segment_frames(segment, self.k, self.num_frames))
        pick = int(torch.randint(len(frames), (1,), generator=generator))
        return self.views.image(self.views.view(frames[pick], camera_id))

    def pseudo_view(self, camera_id: int, segment: int) -> Tensor:
        """Mean of the camera's images at the segment's pseudo frames."""
        wanted = pseudo_frames(segment, self.k, self.num_frames, self.p)
        frames = self._frames_with(camera_id, wanted)
        images = [self.views.image(self.views.view(frame, camera_id)) for frame in frames]
        return torch.stack(images).mean(dim=0)

    def _frames_with(self, camera_id: int, frames: range | list[int]) -> list[int]:
        """The frames among `frames` at which the camera has an image (at least one)."""
        present = [frame for frame in frames if self.views.has_view(frame, camera_id)]
        if not present:
            raise InputError(
                f"camera {camera_id} has no train image in frames {list(frames)} of its segment"
            )
        return present
