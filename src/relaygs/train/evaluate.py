"""Evaluation: score every test camera at every (`frame_stride`-th) frame (docs/method.md)."""

from __future__ import annotations

import time
from typing import Any

import torch

from relaygs.colour_fit import ColourFittedPSNR
from relaygs.data import Scene, View
from relaygs.device import synchronize
from relaygs.errors import InputError
from relaygs.metrics import fg_psnr, psnr, ssim
from relaygs.per_view import METRIC_COLUMNS, PER_VIEW, ViewRecord
from relaygs.train.model_render import ModelRenderer
from relaygs.train.scene_model import SceneModel


def score_model(
    scene: Scene, model: SceneModel, frame_stride: int, device: torch.device
) -> dict[str, Any]:
    """Test metrics of `model` on `scene` at frames 0, stride, 2·stride, …, rendered on `device`."""
    require_its_scene(model, scene)
    model = model.to(device)
    renderer = ModelRenderer(model)
    per_view: list[ViewRecord] = []
    colour_fitted = ColourFittedPSNR()
    rendered, render_seconds = 0, 0.0
    for frame in range(0, scene.num_frames, frame_stride):
        views = scene.views_at(frame, "test")
        if not views:
            continue
        began = time.perf_counter()
        images = renderer.render([view.camera for view in views], views[0].time)
        synchronize(device)  # render FPS counts the GPU's work, not only its launch
        render_seconds += time.perf_counter() - began
        rendered += len(images)
        for view, image in zip(views, images, strict=True):
            per_view.append(view_metrics(scene, view, image.cpu()))
            colour_fitted.add(view.camera.camera_id, image.cpu(), scene.image(view))
    return {
        **{name: _mean(per_view, name) for name in METRIC_COLUMNS},
        "psnr_cf": colour_fitted.value(),
        "render_fps": rendered / render_seconds if render_seconds > 0 else None,
        **model.gaussian_counts(),
        "num_test_images": rendered,
        PER_VIEW: per_view,
    }


def view_metrics(scene: Scene, view: View, pred: torch.Tensor) -> ViewRecord:
    """One test image's frame, camera and METRIC_COLUMNS (fg-PSNR None without a mask)."""
    target = scene.image(view)
    mask = scene.mask(view)
    foreground = None
    if mask is not None and bool(mask.any()):
        foreground = float(fg_psnr(pred, target, mask))
    return {
        "frame": view.frame,
        "camera": view.camera.camera_id,
        "psnr": float(psnr(pred, target)),
        "ssim": float(ssim(pred, target)),
        "fg_psnr": foreground,
    }


def require_its_scene(model: SceneModel, scene: Scene) -> None:
    """Refuse a scene the model was not trained on (frame count, affine cameras)."""
    if model.num_frames != scene.num_frames:
        raise InputError(
            f"the model was trained on {model.num_frames} frames but {scene.root} has "
            f"{scene.num_frames}: use the scene it was trained on"
        )
    train_cameras = sorted({view.camera.camera_id for view in scene.train_views})
    if model.affine_cameras and model.affine_cameras != train_cameras:
        trained = model.affine_cameras
        which = " different ones" if len(trained) == len(train_cameras) else ""
        raise InputError(
            f"the model was trained on {len(trained)} train cameras but {scene.root} has "
            f"{len(train_cameras)}{which}: {_held_out_hint(trained, scene)}"
        )


def _held_out_hint(trained: list[int], scene: Scene) -> str:
    """What to load instead: the scene with the cameras the model did not train on as tests."""
    cameras = {view.camera.camera_id for view in scene.train_views + scene.test_views}
    if not set(trained) <= cameras:
        return "use the scene it was trained on"
    held_out = sorted(cameras - set(trained))
    if not held_out:
        return (
            "it trained on every camera: load the scene with no test cameras "
            "(--test-cameras '[]'), which leaves no held-out view to score"
        )
    ids = ",".join(map(str, held_out))
    return (
        f"it held out cameras {held_out}, so load the scene with those as its test cameras "
        f"(the run's scene.loader.test_cameras; --test-cameras {ids})"
    )


def _mean(records: list[ViewRecord], name: str) -> float | None:
    """Mean of `name` over the records that have it, or None (JSON has no NaN)."""
    values = [record[name] for record in records if record[name] is not None]
    return sum(values) / len(values) if values else None
