"""Where a model's error lies: PSNR over the foreground and the background pixels apart, on the
train or the test views, so that a model's fit to seen views can be set against unseen ones."""

from __future__ import annotations

import torch

from relaygs.data import Scene
from relaygs.metrics import psnr
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.evaluate import require_its_scene
from relaygs.stages.model_render import ModelRenderer
from relaygs.stages.scene_model import SceneModel

SPLIT_METRICS = ("psnr", "fg_psnr", "bg_psnr")
"""Mean per-image PSNR over all pixels, ground-truth foreground pixels, background pixels."""


def error_split(
    scene: Scene,
    artifact: Artifact,
    split: str,
    frame_stride: int = 1,
    device: torch.device | None = None,
) -> dict[str, float | None]:
    """SPLIT_METRICS of the artifact's model over `split`'s views ("train" or "test") at every
    `frame_stride`-th frame, plus their count; fg/bg are None where no view has such pixels."""
    device = device or torch.device("cpu")
    model = SceneModel.from_artifact(artifact)
    require_its_scene(model, scene)
    renderer = ModelRenderer(model.to(device))
    scores: dict[str, list[float]] = {name: [] for name in SPLIT_METRICS}
    for frame in range(0, scene.num_frames, frame_stride):
        views = scene.views_at(frame, split)
        if not views:
            continue
        images = renderer.render([view.camera for view in views], views[0].time)
        for view, image in zip(views, images, strict=True):
            pred, target = image.cpu(), scene.image(view)
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
