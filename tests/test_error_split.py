"""error_split: a model's PSNR over all, foreground and background pixels of train or test views."""

from __future__ import annotations

import math

import pytest
import torch

from relaygs.stages import evaluate
from relaygs.train.error_split import error_split
from relaygs.train.model_render import ModelRenderer


def test_test_split_scores_as_the_evaluator_does(stage_scene, stage_decoupled):
    scores = error_split(stage_scene, stage_decoupled, "test", frame_stride=4)
    metrics = evaluate(stage_scene, stage_decoupled, {"eval": {"frame_stride": 4}})
    assert scores["images"] == metrics["num_test_images"]
    assert scores["psnr"] == pytest.approx(metrics["psnr"], abs=1e-5)
    assert scores["fg_psnr"] == pytest.approx(metrics["fg_psnr"], abs=1e-5)
    assert scores["bg_psnr"] > scores["fg_psnr"]  # the decoupled model holds no movers


def test_train_split_scores_every_train_view_of_the_frames(stage_scene, stage_decoupled):
    scores = error_split(stage_scene, stage_decoupled, "train", frame_stride=4)
    frames = range(0, stage_scene.num_frames, 4)
    assert scores["images"] == sum(len(stage_scene.views_at(f, "train")) for f in frames)
    assert all(scores[name] is not None for name in ("psnr", "fg_psnr", "bg_psnr"))


def test_background_and_foreground_pixels_are_scored_apart(
    stage_scene, stage_decoupled, monkeypatch
):
    """A render exact on the background and black on the foreground: bg-PSNR at the metric's
    100 dB ceiling, fg-PSNR finite and far below it."""
    views_by_camera = {}

    def truth_without_foreground(self, cameras, time):
        images = []
        for camera in cameras:
            view = views_by_camera[(camera.camera_id, time)]
            image = stage_scene.image(view).clone()
            image[stage_scene.mask(view)] = 0.0
            images.append(image)
        return images

    for view in stage_scene.test_views:
        views_by_camera[(view.camera.camera_id, view.time)] = view
    monkeypatch.setattr(ModelRenderer, "render", truth_without_foreground)
    scores = error_split(stage_scene, stage_decoupled, "test", frame_stride=4)
    assert scores["bg_psnr"] == pytest.approx(100.0)
    assert scores["fg_psnr"] < 40.0
    assert torch.isfinite(torch.tensor(scores["psnr"])) and scores["psnr"] < 100.0


def _render_as(monkeypatch, scene, split, image_of):
    """Make every render return `image_of(truth)` for its view's ground truth."""
    views = {(view.camera.camera_id, view.time): view for view in scene.views_at(0, split)}
    views |= {
        (view.camera.camera_id, view.time): view
        for view in (scene.train_views if split == "train" else scene.test_views)
    }

    def render(self, cameras, time):
        return [image_of(scene.image(views[(camera.camera_id, time)])) for camera in cameras]

    monkeypatch.setattr(ModelRenderer, "render", render)


def test_colour_fit_undoes_a_camera_response_the_model_cannot_know(
    stage_scene, stage_decoupled, monkeypatch
):
    _render_as(monkeypatch, stage_scene, "test", lambda truth: truth * 0.8 + 0.05)
    raw = error_split(stage_scene, stage_decoupled, "test", frame_stride=4)
    fitted = error_split(stage_scene, stage_decoupled, "test", frame_stride=4, colour_fit=True)
    assert raw["psnr"] < 30.0
    assert fitted["psnr"] > 60.0 and fitted["images"] == raw["images"]


def test_colour_fit_of_a_flat_render_stays_finite(stage_scene, stage_decoupled, monkeypatch):
    _render_as(monkeypatch, stage_scene, "test", lambda truth: torch.full_like(truth, 0.5))
    fitted = error_split(stage_scene, stage_decoupled, "test", frame_stride=4, colour_fit=True)
    assert all(math.isfinite(fitted[name]) for name in ("psnr", "fg_psnr", "bg_psnr"))
