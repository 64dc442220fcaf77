"""Evaluation: render FPS from the render time only, fg-PSNR over the ground-truth masks."""

from __future__ import annotations

import importlib
import math
from types import SimpleNamespace

import pytest
import torch

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


class _TickingClock:
    """perf_counter that advances by `tick` seconds on every call."""

    def __init__(self, tick: float) -> None:
        self.tick = tick
        self.now = 100.0

    def perf_counter(self) -> float:
        self.now += self.tick
        return self.now


def _evaluated_frames(scene: Scene) -> list[int]:
    return list(range(0, scene.num_frames, STRIDE))


def test_render_fps_is_images_per_render_second(
    stage_deformed: Artifact, stage_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each frame's render is timed by two clock reads, one tick apart: fps = images / time."""
    tick = 0.25
    monkeypatch.setattr(
        evaluate_module, "time", SimpleNamespace(perf_counter=_TickingClock(tick).perf_counter)
    )
    metrics = evaluate(stage_scene, stage_deformed, stage_smoke_cfg(eval={"frame_stride": STRIDE}))
    frames = _evaluated_frames(stage_scene)
    images = len(frames) * len(stage_scene.test_cameras)
    assert metrics["num_test_images"] == images
    assert metrics["render_fps"] == pytest.approx(images / (len(frames) * tick))


def test_render_time_waits_for_the_device(
    stage_deformed: Artifact, stage_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """CUDA renders run asynchronously: the clock stops only once the device has finished."""
    events: list[str] = []
    clock = SimpleNamespace(perf_counter=lambda: events.append("clock") or 0.0)
    monkeypatch.setattr(evaluate_module, "time", clock)
    monkeypatch.setattr(evaluate_module, "synchronize", lambda device: events.append(str(device)))
    evaluate(stage_scene, stage_deformed, stage_smoke_cfg(eval={"frame_stride": STRIDE}))
    assert events == ["clock", "cpu", "clock"] * len(_evaluated_frames(stage_scene))


def _masked_psnr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float:
    squared = (pred - target).square()[mask]  # [pixels, 3]
    return 10 * math.log10(1.0 / max(float(squared.mean()), 1e-10))


def test_fg_psnr_runs_over_the_foreground_masks(
    stage_deformed: Artifact, stage_scene: Scene
) -> None:
    metrics = evaluate(stage_scene, stage_deformed, stage_smoke_cfg(eval={"frame_stride": STRIDE}))
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    scores = []
    for frame in _evaluated_frames(stage_scene):
        views = stage_scene.views_at(frame, "test")
        images = renderer.render([view.camera for view in views], views[0].time)
        for view, image in zip(views, images, strict=True):
            mask = stage_scene.mask(view)
            if mask is not None and bool(mask.any()):
                scores.append(_masked_psnr(image, stage_scene.image(view), mask))
    assert scores  # the juggle scene has foreground in its test views
    assert metrics["fg_psnr"] == pytest.approx(sum(scores) / len(scores), abs=1e-4)
    assert abs(metrics["fg_psnr"] - metrics["psnr"]) > 0.1  # not the full-image score


def test_per_view_records_score_each_test_image_and_average_to_the_metrics(
    stage_deformed: Artifact, stage_scene: Scene
) -> None:
    metrics = evaluate(stage_scene, stage_deformed, stage_smoke_cfg(eval={"frame_stride": STRIDE}))
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
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    last = stage_scene.views_at(expected[-1][0], "test")[-1]
    image = renderer.render([last.camera], last.time)[0]
    assert records[-1]["psnr"] == pytest.approx(float(psnr(image, stage_scene.image(last))))
    assert records[-1]["ssim"] == pytest.approx(float(ssim(image, stage_scene.image(last))))
