"""Evaluation: render FPS from the render time only, fg-PSNR over the ground-truth masks."""

from __future__ import annotations

import importlib
import math
from types import SimpleNamespace

import pytest

from conftest import stage_smoke_cfg
from relaygs.data import Scene
from relaygs.metrics import psnr, ssim
from relaygs.per_view import METRIC_COLUMNS, PER_VIEW
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import SceneModel, evaluate
from relaygs.train.model_render import ModelRenderer

STRIDE = 3
# the module (the package's `evaluate` attribute is the function of the same name)
evaluate_module = importlib.import_module("relaygs.train.evaluate")


def _evaluated_frames(scene: Scene) -> list[int]:
    return list(range(0, scene.num_frames, STRIDE))


def test_render_fps_is_images_per_render_second_once_the_device_finished(
    stage_deformed: Artifact, stage_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each frame's render is timed by two clock reads a tick apart, the second once the device
    has finished (CUDA renders run asynchronously): fps = images / time."""
    tick, events = 0.25, []

    def perf_counter() -> float:
        events.append("clock")
        return tick * events.count("clock")  # each read one tick after the one before

    monkeypatch.setattr(evaluate_module, "time", SimpleNamespace(perf_counter=perf_counter))
    monkeypatch.setattr(evaluate_module, "synchronize", lambda device: events.append(str(device)))
    metrics = evaluate(stage_scene, stage_deformed, stage_smoke_cfg(eval={"frame_stride": STRIDE}))
    frames = _evaluated_frames(stage_scene)
    assert events == ["clock", "cpu", "clock"] * len(frames)
    images = len(frames) * len(stage_scene.test_cameras)
    assert metrics["num_test_images"] == images
    assert metrics["render_fps"] == pytest.approx(images / (len(frames) * tick))


def test_fg_psnr_runs_over_the_masks_and_per_view_records_average_to_the_metrics(
    stage_deformed: Artifact, stage_scene: Scene
) -> None:
    metrics = evaluate(stage_scene, stage_deformed, stage_smoke_cfg(eval={"frame_stride": STRIDE}))
    for key in ("psnr", "ssim", "fg_psnr", "render_fps"):
        assert math.isfinite(metrics[key]) and metrics[key] > 0, key
    assert metrics["num_gaussians"] == stage_deformed.meta["counts"]["total"]
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    scores = []
    for frame in _evaluated_frames(stage_scene):
        views = stage_scene.views_at(frame, "test")
        images = renderer.render([view.camera for view in views], views[0].time)
        for view, image in zip(views, images, strict=True):
            mask = stage_scene.mask(view)
            if mask is not None and bool(mask.any()):
                squared = (image - stage_scene.image(view)).square()[mask]  # [pixels, 3]
                scores.append(10 * math.log10(1.0 / max(float(squared.mean()), 1e-10)))
    assert scores  # the juggle scene has foreground in its test views
    assert metrics["fg_psnr"] == pytest.approx(sum(scores) / len(scores), abs=1e-4)
    assert abs(metrics["fg_psnr"] - metrics["psnr"]) > 0.1  # not the full-image score
    records = metrics[PER_VIEW]
    expected = [
        (view.frame, view.camera.camera_id)
        for frame in _evaluated_frames(stage_scene)
        for view in stage_scene.views_at(frame, "test")
    ]
    assert [(r["frame"], r["camera"]) for r in records] == expected
    assert len(records) == metrics["num_test_images"]
    for name in METRIC_COLUMNS:
        scored = [r[name] for r in records if r[name] is not None]
        assert metrics[name] == pytest.approx(sum(scored) / len(scored), abs=1e-9)
    assert len({round(r["psnr"], 3) for r in records}) > 1  # each image its own score
    last = stage_scene.views_at(expected[-1][0], "test")[-1]
    image = renderer.render([last.camera], last.time)[0]
    assert records[-1]["psnr"] == pytest.approx(float(psnr(image, stage_scene.image(last))))
    assert records[-1]["ssim"] == pytest.approx(float(ssim(image, stage_scene.image(last))))
