"""Evaluation: render every test camera at every frame (or every `frame_stride`-th) and score.

PSNR and SSIM are per image, averaged; fg-PSNR runs over ground-truth foreground pixels of
the images that have a non-empty mask (None when the scene has no masks); render FPS counts
rendering only (no metric time). Storage is the store's to report (`Manifest.size_mb`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from relaygs.data import Scene
from relaygs.device import synchronize
from relaygs.errors import InputError
from relaygs.metrics import fg_psnr, psnr, ssim
from relaygs.pipeline.artifact import Artifact
from relaygs.stages.config import parse_section, require
from relaygs.stages.model_render import ModelRenderer
from relaygs.stages.scene_model import SceneModel
from relaygs.stages.train_settings import TrainSettings


@dataclass(frozen=True)
class EvalSettings:
    """`cfg["eval"]`: evaluate frames 0, stride, 2·stride, …"""

    frame_stride: int = 1

    def __post_init__(self) -> None:
        """The stride is a positive frame count."""
        require(self.frame_stride >= 1, "eval.frame_stride", self.frame_stride, "an int >= 1")

    @classmethod
    def from_config(cls, data: Mapping[str, Any] | None) -> EvalSettings:
        """Parse `cfg["eval"]` (missing keys keep defaults)."""
        return parse_section(cls, data, "eval")


def evaluate(scene: Scene, artifact: Artifact, cfg: Mapping[str, Any]) -> dict[str, Any]:
    """Test metrics of the artifact's model on `scene` (keys in the module docstring, plus
    Gaussian counts and the number of test images)."""
    settings = EvalSettings.from_config(cfg.get("eval"))
    device = TrainSettings.from_config(cfg.get("train")).torch_device()
    model = SceneModel.from_artifact(artifact)
    require_its_scene(model, scene)
    model = model.to(device)
    renderer = ModelRenderer(model)
    psnrs, ssims, fg_psnrs = [], [], []
    rendered, render_seconds = 0, 0.0
    for frame in range(0, scene.num_frames, settings.frame_stride):
        views = scene.views_at(frame, "test")
        if not views:
            continue
        began = time.perf_counter()
        images = renderer.render([view.camera for view in views], views[0].time)
        synchronize(device)  # render FPS counts the GPU's work, not only its launch
        render_seconds += time.perf_counter() - began
        rendered += len(images)
        for view, image in zip(views, images, strict=True):
            pred = image.cpu()
            target = scene.image(view)
            psnrs.append(float(psnr(pred, target)))
            ssims.append(float(ssim(pred, target)))
            mask = scene.mask(view)
            if mask is not None and bool(mask.any()):
                fg_psnrs.append(float(fg_psnr(pred, target, mask)))
    n_bg, n_fg = len(model.background), len(model.foreground)
    return {
        "psnr": _mean(psnrs),
        "ssim": _mean(ssims),
        "fg_psnr": _mean(fg_psnrs),
        "render_fps": rendered / render_seconds if render_seconds > 0 else None,
        "num_gaussians": n_bg + n_fg,
        "num_bg": n_bg,
        "num_fg": n_fg,
        "num_test_images": rendered,
    }


def require_its_scene(model: SceneModel, scene: Scene) -> None:
    """Refuse a scene the model cannot have been trained on, whose renders and scores would mean
    nothing: another frame count, or other train cameras than its colour affine was fit to."""
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
            f"{len(train_cameras)}{which}: use the scene it was trained on"
        )


def _mean(values: list[float]) -> float | None:
    """Mean, or None for no values (e.g. fg-PSNR without masks; JSON has no NaN)."""
    return sum(values) / len(values) if values else None
