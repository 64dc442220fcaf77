"""error_split: a model's PSNR over all, foreground and background pixels of train or test views."""

from __future__ import annotations

import math

import pytest
import torch

from relaygs.stages import evaluate
from relaygs.train.error_split import error_split
from relaygs.train.model_render import ModelRenderer


def test_the_test_split_scores_as_the_evaluator_does_the_train_split_every_view(
    stage_scene, stage_decoupled
):
    scores = error_split(stage_scene, stage_decoupled, "test", frame_stride=4)
    fitted = error_split(stage_scene, stage_decoupled, "test", frame_stride=4, colour_fit=True)
    metrics = evaluate(stage_scene, stage_decoupled, {"eval": {"frame_stride": 4}})
    assert scores["images"] == metrics["num_test_images"]
    assert scores["psnr"] == pytest.approx(metrics["psnr"], abs=1e-5)
    assert scores["fg_psnr"] == pytest.approx(metrics["fg_psnr"], abs=1e-5)
    assert scores["bg_psnr"] > scores["fg_psnr"]  # the decoupled model holds no movers
    assert metrics["psnr_cf"] == pytest.approx(fitted["psnr"], abs=1e-4)
    assert metrics["psnr_cf"] >= metrics["psnr"] - 1e-4  # the fit includes gain 1, offset 0
    scores = error_split(stage_scene, stage_decoupled, "train", frame_stride=4)
    frames = range(0, stage_scene.num_frames, 4)
    assert scores["images"] == sum(len(stage_scene.views_at(f, "train")) for f in frames)
    assert all(scores[name] is not None for name in ("psnr", "fg_psnr", "bg_psnr"))


def _render_as(monkeypatch, scene, image_of):
    """Make every render of a test view return `image_of(view)`."""
    views = {(view.camera.camera_id, view.time): view for view in scene.test_views}

    def render(self, cameras, time):
        return [image_of(views[(camera.camera_id, time)]) for camera in cameras]

    monkeypatch.setattr(ModelRenderer, "render", render)


def test_stubbed_renders_score_fg_and_bg_apart_and_colour_fit_undoes_a_response(
    stage_scene, stage_decoupled, monkeypatch
):
    _render_as(monkeypatch, stage_scene, lambda view: stage_scene.image(view) * 0.8 + 0.05)
    raw = error_split(stage_scene, stage_decoupled, "test", frame_stride=4)
    fitted = error_split(stage_scene, stage_decoupled, "test", frame_stride=4, colour_fit=True)
    assert raw["psnr"] < 30.0
    assert fitted["psnr"] > 60.0 and fitted["images"] == raw["images"]
    _render_as(monkeypatch, stage_scene, lambda view: torch.full_like(stage_scene.image(view), 0.5))
    fitted = error_split(stage_scene, stage_decoupled, "test", frame_stride=4, colour_fit=True)
    assert all(math.isfinite(fitted[name]) for name in ("psnr", "fg_psnr", "bg_psnr"))

    # exact on the background, black on the foreground: bg-PSNR at the 100 dB ceiling
    def without_foreground(view):
        return stage_scene.image(view).masked_fill(stage_scene.mask(view)[..., None], 0.0)

    _render_as(monkeypatch, stage_scene, without_foreground)
    scores = error_split(stage_scene, stage_decoupled, "test", frame_stride=4)
    assert scores["bg_psnr"] == pytest.approx(100.0)
    assert scores["fg_psnr"] < 40.0
    assert torch.isfinite(torch.tensor(scores["psnr"])) and scores["psnr"] < 100.0
