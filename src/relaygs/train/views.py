"""Training views of a scene: lookup by (frame, camera), random batches, images on the device."""

from __future__ import annotations

import torch
from torch import Tensor

from relaygs.data import Scene, View
from relaygs.errors import InputError


def views_per_slot(batch_views: int, slots: int) -> list[int]:
    """How a step's `batch_views` views split among `slots` frames or segments, round-robin
    (slots beyond the views get none, and are skipped)."""
    return [count for slot in range(slots) if (count := len(range(slot, batch_views, slots)))]


class TrainViews:
    """The scene's train views indexed by frame, with random draws from a torch.Generator."""

    def __init__(self, scene: Scene, device: torch.device) -> None:
        if not scene.train_views:
            raise InputError(f"scene {scene.name!r}: no training views")
        self.scene = scene
        self.device = device
        self.all_views = list(scene.train_views)
        self.by_frame: dict[int, list[View]] = {}
        for view in self.all_views:
            self.by_frame.setdefault(view.frame, []).append(view)
        self._by_key = {(view.frame, view.camera.camera_id): view for view in self.all_views}

    def image(self, view: View) -> Tensor:
        """The view's ground-truth image [H,W,3] on the training device."""
        return self.scene.image(view).to(self.device)

    def has_view(self, frame: int, camera_id: int) -> bool:
        return (frame, camera_id) in self._by_key

    def view(self, frame: int, camera_id: int) -> View:
        """The train view of `camera_id` at `frame`."""
        view = self._by_key.get((frame, camera_id))
        if view is None:
            raise InputError(
                f"scene {self.scene.name!r}: camera {camera_id} has no train image at frame {frame}"
            )
        return view

    def random_views(self, count: int, generator: torch.Generator) -> list[View]:
        """`count` views drawn uniformly (with replacement) over every frame and train camera."""
        picks = torch.randint(len(self.all_views), (count,), generator=generator)
        return [self.all_views[int(i)] for i in picks]

    def random_views_at(self, frame: int, count: int, generator: torch.Generator) -> list[View]:
        """`count` views of frame `frame` with distinct cameras while there are enough of them."""
        views = self.by_frame.get(frame)
        if not views:
            raise InputError(f"scene {self.scene.name!r}: no train views at frame {frame}")
        order = torch.randperm(len(views), generator=generator)
        if count > len(views):
            extra = torch.randint(len(views), (count - len(views),), generator=generator)
            order = torch.cat([order, extra])
        return [views[int(i)] for i in order[:count]]
