"""Decouple (and the static warm-up): straight-through mask, well-formed output, separation."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest
import torch

import relaygs.stages.decouple as decouple_module
from conftest import stage_smoke_cfg
from refusals import refused
from relaygs.data import Scene, View
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import SPECS, SceneModel
from relaygs.stages.decouple import straight_through_mask
from relaygs.train.initial import initial_gaussians
from relaygs.train.views import TrainViews

# On the test scene, after 200 steps: ≥ 60 % of the cloud's mover points end nearest to a
# Gaussian marked foreground, ≥ 85 % of its static (floor, wall, props) points nearest to
# background. (Measured: about 80 % and 93 %.)
MOVER_MARKED_FG = 0.6
STATIC_MARKED_BG = 0.85


def test_straight_through_mask_is_hard_forward_and_sigmoid_backward() -> None:
    logits = torch.tensor([-3.0, -0.1, 0.1, 2.0], requires_grad=True)
    mask = straight_through_mask(logits, threshold=0.5)
    assert mask.tolist() == [0.0, 0.0, 1.0, 1.0]
    mask.sum().backward()
    sigmoid = torch.sigmoid(logits.detach())
    torch.testing.assert_close(logits.grad, sigmoid * (1 - sigmoid))


def test_output_is_well_formed_shows_fg_at_frame_0_only_and_marks_the_movers(
    stage_decoupled: Artifact, stage_scene: Scene
) -> None:
    tensors = stage_decoupled.tensors
    for name, tensor in tensors.items():
        if tensor.is_floating_point():
            assert torch.isfinite(tensor).all(), name
    counts = stage_decoupled.meta["counts"]
    is_fg = tensors["is_fg"]
    assert is_fg.dtype == torch.bool and is_fg.shape == (counts["total"],)
    assert not is_fg[: counts["bg"]].any() and is_fg[counts["bg"] :].all()
    assert counts["bg"] > 0 and counts["fg"] > 0
    assert tensors["segment"].dtype == torch.int32
    assert torch.equal(tensors["segment"], torch.where(is_fg, 0, -1).int())
    assert tensors["bg.means"].shape == (counts["bg"], 3)
    assert tensors["fg.means"].shape == (counts["fg"], 3)
    assert not any("mask_logit" in name for name in tensors)
    assert stage_decoupled.meta["num_frames"] == stage_scene.num_frames
    metrics = stage_decoupled.meta["metrics"]
    assert metrics["final_loss"] < metrics["initial_loss"]
    model = SceneModel.from_artifact(stage_decoupled)
    assert model.foreground_rows(0).numel() == len(model.foreground)
    assert model.foreground_rows(3).numel() == 0
    means = torch.cat([model.background.means, model.foreground.means]).detach()
    nearest = torch.cdist(stage_scene.points.xyz, means).argmin(dim=1)
    marked_fg = stage_decoupled.tensors["is_fg"][nearest]
    on_mover = stage_scene.points.is_fg
    assert on_mover.any() and (~on_mover).any()
    assert marked_fg[on_mover].float().mean() >= MOVER_MARKED_FG
    assert (~marked_fg[~on_mover]).float().mean() >= STATIC_MARKED_BG


@pytest.mark.parametrize(("mask_init", "noted"), [(30.0, True), (-30.0, False)])
def test_a_decouple_that_marks_no_foreground_says_so(
    stage_scene: Scene, mask_init: float, noted: bool
) -> None:
    cfg = stage_smoke_cfg(decouple={"steps": 2, "mask_init": mask_init})
    artifact = SPECS["decouple"].run(stage_scene, {}, cfg)
    assert (artifact.meta["metrics"]["num_fg"] == 0) == noted
    note = decouple_module.NO_FOREGROUND_NOTE.format(steps=2)
    assert artifact.notes == ((note,) if noted else ())  # said by every run that uses it


def test_warmup_is_all_background(stage_scene: Scene) -> None:
    artifact = SPECS["warmup"].run(stage_scene, {}, stage_smoke_cfg())
    assert artifact.stage == "warmup"
    assert artifact.meta["counts"]["fg"] == 0
    assert not artifact.tensors["is_fg"].any()
    assert (artifact.tensors["segment"] == -1).all()
    assert torch.isfinite(artifact.tensors["bg.means"]).all()
    # the smoke budget densifies and prunes: the count moved off the initial 1500
    assert artifact.meta["counts"]["bg"] != 1500


def test_every_batch_has_frame0_views_rendered_without_the_mask(
    stage_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`frame0_views` of each step's `batch_views` are frame-0 views, and exactly those are
    rendered with every Gaussian (no opacity × M): the separation needs frame 0 in every batch."""
    frame0_views, batch_views, steps = 2, 4, 4
    batches: list[list[View]] = []  # per step: the views whose targets were read
    renders: list[list[tuple[int, bool]]] = []  # per step: (cameras, masked) per splat call

    class RecordingViews(TrainViews):
        def image(self, view: View) -> torch.Tensor:
            batches[-1].append(view)
            return super().image(view)

    real_run_training, real_splat = decouple_module.run_training, decouple_module.splat

    def run_training(stage: str, session: Any, count: int, train: Any, step_fn: Any, counts: Any):
        def recorded_step(step: int) -> Any:
            batches.append([])
            renders.append([])
            return step_fn(step)

        return real_run_training(stage, session, count, train, recorded_step, counts)

    def splat(parts: list[Any], cameras: list[Any], *args: Any, **kwargs: Any) -> Any:
        renders[-1].append((len(cameras), parts[0].opacity_factor is not None))
        return real_splat(parts, cameras, *args, **kwargs)

    monkeypatch.setattr(decouple_module, "TrainViews", RecordingViews)
    monkeypatch.setattr(decouple_module, "run_training", run_training)
    monkeypatch.setattr(decouple_module, "splat", splat)
    no_density = {"densify_until": 0, "opacity_reset_every": 0}
    section = {"steps": steps, "frame0_views": frame0_views, "init_points": 300}
    cfg = stage_smoke_cfg(
        decouple={**section, "densify": no_density}, train={"batch_views": batch_views}
    )
    SPECS["decouple"].run(stage_scene, {}, cfg)
    assert len(batches) == steps
    for views, calls in zip(batches, renders, strict=True):
        assert len(views) == batch_views
        at_zero = sum(view.frame == 0 for view in views)
        assert at_zero >= frame0_views
        unmasked = sum(count for count, masked in calls if not masked)
        masked = sum(count for count, masked in calls if masked)
        assert (unmasked, masked) == (at_zero, batch_views - at_zero)


@pytest.mark.parametrize("stage", ["decouple", "warmup"])
def test_a_scene_in_huge_units_is_refused_before_its_sizes_freeze(stage_scene: Scene, stage: str):
    # ×1e6: neighbours ~1e5 units apart, beyond the renderer's largest Gaussian (e^10):
    # sizes past the cap get no gradient, and the scene trained to a black image
    points = stage_scene.points
    huge = dataclasses.replace(
        stage_scene, points=dataclasses.replace(points, xyz=points.xyz * 1e6)
    )
    cfg = stage_smoke_cfg(**{stage: {"steps": 1}})
    with refused(InputError, "initial points", "2.2e+04"):
        SPECS[stage].run(huge, {}, cfg)
    initial_gaussians(stage_scene, None, 0.1, 0, 0)  # its own units: fine
