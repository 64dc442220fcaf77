"""The relay stage's per-segment training targets (pseudo-views) over a SegmentPlan."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from relaygs.errors import InputError
from relaygs.train.segment_plan import SegmentPlan
from relaygs.train.views import TrainViews


def pseudo_frames(frames: range, p: int) -> list[int]:
    """p frames spread uniformly over a segment's `frames` (first, …, last; p = 3 adds the
    middle); fewer when the segment is shorter; p = 1 takes the middle frame."""
    first, last = frames[0], frames[-1]
    if p == 1:
        return [(first + last) // 2]
    spread = np.rint(np.linspace(first, last, p)).astype(int)
    return sorted({int(frame) for frame in spread})


class SegmentTargets:
    """Training targets for (camera, segment): the pseudo-view (mean image of the segment's
    pseudo frames, cached) or, without pseudo-views, the image at one random frame."""

    def __init__(self, views: TrainViews, plan: SegmentPlan, p: int, pseudo_views: bool) -> None:
        self.views = views
        self.plan = plan
        self.p = p
        self.pseudo_views = pseudo_views
        self._cache: dict[tuple[int, int], Tensor] = {}

    def target(self, camera_id: int, segment: int, generator: torch.Generator) -> Tensor:
        """The [H,W,3] target of `camera_id` for `segment`."""
        if self.pseudo_views:  # the mean of the camera's images at the pseudo frames, cached
            key = (camera_id, segment)
            if key not in self._cache:
                wanted = pseudo_frames(self.plan.frames(segment), self.p)
                frames = self._frames_with(camera_id, wanted)
                images = [self.views.image(self.views.view(frame, camera_id)) for frame in frames]
                self._cache[key] = torch.stack(images).mean(dim=0)
            return self._cache[key]
        frames = self._frames_with(camera_id, self.plan.frames(segment))
        pick = int(torch.randint(len(frames), (1,), generator=generator))
        return self.views.image(self.views.view(frames[pick], camera_id))

    def _frames_with(self, camera_id: int, frames: range | list[int]) -> list[int]:
        """The frames among `frames` at which the camera has an image (at least one)."""
        present = [frame for frame in frames if self.views.has_view(frame, camera_id)]
        if not present:
            raise InputError(
                f"camera {camera_id} has no train image in frames {list(frames)} of its segment"
            )
        return present
