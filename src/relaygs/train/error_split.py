"""PSNR over foreground and background pixels apart, on the train or the test views, optionally
after fitting each camera's colour response (which no model can know for a held-out camera)."""

from __future__ import annotations

from collections import defaultdict

import torch

from relaygs.colour_fit import channel_fit, channel_moments
from relaygs.data import Scene, View
from relaygs.metrics import psnr
from relaygs.pipeline.artifact import Artifact
from relaygs.train.evaluate import require_its_scene
from relaygs.train.model_render import ModelRenderer
from relaygs.train.scene_model import SceneModel

SPLIT_METRICS = ("psnr", "fg_psnr", "bg_psnr")  # over all, foreground, background pixels


def error_split(
    scene: Scene,
    artifact: Artifact,
    split: str,
    frame_stride: int = 1,
    device: torch.device | None = None,
    colour_fit: bool = False,
) -> dict[str, float | None]:
    """SPLIT_METRICS (None without such pixels) and the image count of the artifact's model over
    `split`'s views at every `frame_stride`-th frame, through `colour_fitted` if asked."""
    device = device or torch.device("cpu")
    model = SceneModel.from_artifact(artifact)
    require_its_scene(model, scene)
    renderer = ModelRenderer(model.to(device))
    renders: list[tuple[View, torch.Tensor]] = []
    for frame in range(0, scene.num_frames, frame_stride):
        views = scene.views_at(frame, split)
        if views:
            images = renderer.render([view.camera for view in views], views[0].time)
            renders += [(view, image.cpu()) for view, image in zip(views, images, strict=True)]
    if colour_fit:
        renders = colour_fitted(scene, renders)
    scores: dict[str, list[float]] = {name: [] for name in SPLIT_METRICS}
    for view, pred in renders:
        target = scene.image(view)
        scores["psnr"].append(float(psnr(pred, target)))
        mask = scene.mask(view)
        if mask is None:
            continue
        for name, pixels in (("fg_psnr", mask), ("bg_psnr", ~mask)):
            if bool(pixels.any()):
                scores[name].append(float(psnr(pred, target, pixels)))
    result: dict[str, float | None] = {
        name: sum(values) / len(values) if values else None for name, values in scores.items()
    }
    result["images"] = len(scores["psnr"])
    return result


def colour_fitted(
    scene: Scene, renders: list[tuple[View, torch.Tensor]]
) -> list[tuple[View, torch.Tensor]]:
    """Each render (clamped) through its camera's fitted channel gain and offset, unclipped, so
    the PSNR over all pixels is the evaluation's `psnr_cf`."""
    by_camera: dict[int, list[tuple[View, torch.Tensor]]] = defaultdict(list)
    for view, image in renders:
        by_camera[view.camera.camera_id].append((view, image.clamp(0.0, 1.0)))
    fitted = []
    for items in by_camera.values():
        pred = torch.stack([image for _, image in items])
        target = torch.stack([scene.image(view) for view, _ in items])
        gain, offset = channel_fit(channel_moments(pred, target), pred[..., 0].numel())
        gain, offset = gain.to(pred.dtype), offset.to(pred.dtype)
        fitted += [(view, image * gain + offset) for view, image in items]
    return fitted
