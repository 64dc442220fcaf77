"""Render a stage's model at any camera and time: evaluation, previews and image logging."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from relaygs.data import Camera
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.train.motion import deformed_parts
from relaygs.train.render import Part, part_of, splat
from relaygs.train.scene_model import SceneModel


class ModelRenderer:
    """Renders one SceneModel (static, relay copies or deformed) without gradients."""

    def __init__(self, model: SceneModel) -> None:
        self.model = model
        self.sh_degree = max(model.background.active_sh_degree, model.foreground.active_sh_degree)
        self._affine_rows = {camera_id: row for row, camera_id in enumerate(model.affine_cameras)}

    def frame_at(self, time: float) -> int:
        """The frame nearest to `time` in [0, 1] (a time outside it: the first or last)."""
        if not math.isfinite(time):
            raise InputError(f"render time must be a finite number in [0, 1], got {time!r}")
        frames = self.model.num_frames
        return min(max(round(time * (frames - 1)), 0), frames - 1)

    @torch.no_grad()
    def parts_at(self, time: float) -> list[Part]:
        """The background and foreground Gaussians shown at `time` in [0, 1]: the copy of the
        nearest frame's segment; a deformed model evaluates its field at exactly `time`."""
        model = self.model
        rows = model.foreground_rows(self.frame_at(time))
        if model.field is not None:
            return deformed_parts(
                model.background, model.foreground, rows, model.field, time, self.sh_degree
            )
        return [
            part_of("bg", model.background, self.sh_degree, frozen=True),
            part_of("fg", model.foreground, self.sh_degree, rows=rows, frozen=True),
        ]

    @torch.no_grad()
    def render(self, cameras: list[Camera], time: float) -> list[Tensor]:
        """Images [H,W,3] in [0, 1] of the model at `time`, colour affine on train cameras."""
        model = self.model
        images = splat(self.parts_at(time), cameras, self.sh_degree, **model.blur()).images
        out = []
        for camera, image in zip(cameras, images, strict=True):
            row = self._affine_rows.get(camera.camera_id)
            if model.affine is not None and row is not None:
                image = model.affine(image, row)
            out.append(image.clamp(0.0, 1.0))
        return out


def render_model(artifact: Artifact, camera: Camera, time: float) -> Tensor:
    """The artifact's model seen from `camera` at `time` in [0, 1]: [H,W,3] in [0, 1]."""
    return ModelRenderer(SceneModel.from_artifact(artifact)).render([camera], time)[0]
