"""Deform: γ as (1 + e^γ) on relay Gaussians only, MLP sets, colour affine, loss, metrics."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import pytest
import torch

import relaygs.stages.deform as deform_module
from conftest import stage_smoke_cfg
from relaygs.data import Scene, View, load_scene
from relaygs.field import DeformationField, Deltas
from relaygs.model import GaussianSet
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import SPECS, SceneModel
from relaygs.train.motion import deformed_parts
from relaygs.train.scene_model import build_field
from relaygs.train.views import TrainViews


def _random_set(count: int, generator: torch.Generator) -> GaussianSet:
    xyz = torch.rand(count, 3, generator=generator) * 2 - 1
    return GaussianSet.from_points(xyz, torch.rand(count, 3, generator=generator))


def _moving_field(isolate: bool):
    settings = {
        "aabb": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]],
        "time_resolution": 4,
        "isolate_fg_bg": isolate,
        "multires": [1],
        "spatial_resolution": 8,
        "channels": 4,
        "width": 8,
        "depth": 0,
    }
    field = build_field(settings, seed=3)
    generator = torch.Generator().manual_seed(5)
    with torch.no_grad():  # non-zero position heads, so Δμ differs per Gaussian and set
        for mlp in field.mlp_sets.values():
            last = mlp.heads["dxyz"][-1]
            last.weight.copy_(torch.randn(last.weight.shape, generator=generator) * 0.1)
            last.bias.copy_(torch.randn(last.bias.shape, generator=generator) * 0.1)
    return field


@pytest.mark.parametrize(("isolate", "gamma"), [(True, True), (False, True), (True, False)])
def test_gamma_scales_relay_motion_only(isolate: bool, gamma: bool) -> None:
    """Relay Gaussians move by (1 + e^γ) Δμ with γ, by plain Δμ without; the rest by Δμ."""
    generator = torch.Generator().manual_seed(0)
    background, foreground = _random_set(7, generator), _random_set(5, generator)
    scale = torch.ones(5, 1)
    if gamma:
        foreground.add_param("gamma", torch.randn(5, 3, generator=generator))
        scale = 1 + torch.exp(foreground.params["gamma"].detach())
    field = _moving_field(isolate)
    rows = torch.tensor([0, 2, 3])
    bg, fg = deformed_parts(background, foreground, rows, field, 0.4, sh_degree=0)
    xyz = torch.cat([background.means, foreground.means[rows]]).detach()
    dmu = field(xyz, 0.4, 7).dxyz.detach()
    assert dmu.abs().min() > 0
    torch.testing.assert_close(bg.means.detach(), xyz[:7] + dmu[:7])
    torch.testing.assert_close(fg.means.detach(), xyz[7:] + scale[rows] * dmu[7:])


def test_deform_output_and_its_fitted_colour_affine(
    stage_deformed: Artifact, stage_scene: Scene
) -> None:
    tensors = stage_deformed.tensors
    for name, tensor in tensors.items():
        if tensor.is_floating_point():
            assert torch.isfinite(tensor).all(), name
    assert "fg.param.gamma" in tensors
    assert any(name.startswith("field.mlp_sets.foreground.") for name in tensors)
    assert any(name.startswith("field.mlp_sets.background.") for name in tensors)
    assert not any(name.startswith("field.mlp_sets.all.") for name in tensors)
    # the juggle preset declares colour inconsistency: one affine row per train camera
    assert "color_inconsistency" in stage_scene.effects
    assert tensors["affine.log_gain"].shape == (len(stage_scene.train_cameras), 3)
    # the affine (identity at init) takes part in the training loss: it moves off the identity
    assert tensors["affine.log_gain"].abs().amax() > 0
    assert tensors["affine.offset"].abs().amax() > 0
    assert stage_deformed.meta["field"]["time_resolution"] == math.ceil(stage_scene.num_frames / 2)


def test_four_dgs_baseline_has_one_mlp_set_and_no_gamma(stage_scene: Scene) -> None:
    cfg = stage_smoke_cfg(warmup={"steps": 4}, deform={"isolate_fg_bg": False, "gamma": False})
    warm = SPECS["warmup"].run(stage_scene, {}, cfg)
    deformed = SPECS["deform"].run(stage_scene, {"warmup": warm}, cfg)
    model = SceneModel.from_artifact(deformed)
    assert list(model.field.mlp_sets) == ["all"]
    assert "gamma" not in model.foreground.params and len(model.foreground) == 0


def test_bfloat16_products_train_finite_and_reload_in_bfloat16(
    stage_scene: Scene, stage_relayed: Artifact
) -> None:
    cfg = stage_smoke_cfg(deform={"steps": 6, "matmul_dtype": "bfloat16"})
    deformed = SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg)
    for name, tensor in deformed.tensors.items():
        assert tensor.dtype != torch.bfloat16, name  # the parameters stay float32
        if tensor.is_floating_point():
            assert torch.isfinite(tensor).all(), name
    assert deformed.meta["field"]["matmul_dtype"] == "bfloat16"
    model = SceneModel.from_artifact(deformed)  # rendering uses the products it trained with
    assert all(mlp.reduced_dtype == torch.bfloat16 for mlp in model.field.mlp_sets.values())


def test_colour_affine_only_when_the_scene_asks_and_no_copies_show_their_one_copy(
    stage_scene_path, stage_decoupled: Artifact
) -> None:
    plain = load_scene(stage_scene_path, max_points=500, effects=[])
    cfg = stage_smoke_cfg(deform={"steps": 2})
    deformed = SPECS["deform"].run(plain, {"decouple": stage_decoupled}, cfg)
    assert not any(name.startswith("affine.") for name in deformed.tensors)
    assert deformed.meta["affine_cameras"] == []
    model = SceneModel.from_artifact(deformed)  # a decouple upstream: one copy at every frame
    for frame in (0, 3, plain.num_frames - 1):
        assert model.foreground_rows(frame).numel() == len(model.foreground) > 0
    forced = stage_smoke_cfg(deform={"steps": 2, "color_affine": True})
    assert (
        "affine.offset" in SPECS["deform"].run(plain, {"decouple": stage_decoupled}, forced).tensors
    )


def test_training_loss_falls(stage_scene: Scene, stage_relayed: Artifact) -> None:
    smoke = stage_smoke_cfg()["deform"]
    no_reset = {  # an opacity reset would lift the loss right before the final window
        key: {**smoke[key], "opacity_reset_every": 0} for key in ("densify_bg", "densify_fg")
    }
    cfg = stage_smoke_cfg(deform={"steps": 60, **no_reset})
    metrics = SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg).meta["metrics"]
    assert metrics["final_loss"] < metrics["initial_loss"]


def test_every_field_delta_is_added_to_its_parameter() -> None:
    """Position, log-scale, quaternion and opacity logit each move by the field's delta (the
    deltas are on pre-activation values), for the background and the shown foreground rows."""
    generator = torch.Generator().manual_seed(2)
    background, foreground = _random_set(4, generator), _random_set(6, generator)
    rows = torch.tensor([1, 4, 5])
    widths = {"dxyz": 3, "dscale": 3, "drot": 4, "dopacity": 1}
    d = Deltas(**{k: torch.randn(4 + 3, w, generator=generator) for k, w in widths.items()})
    calls = []  # a stand-in motion field: these deltas, whatever its inputs

    def stub(xyz, time, count):
        return calls.append((time, count)) or d

    parts = deformed_parts(background, foreground, rows, stub, 0.25, sh_degree=0)
    assert calls == [(0.25, 4)]  # background rows first, then the 3 shown foreground
    base = {
        name: torch.cat([background.params[name], foreground.params[name][rows]]).detach()
        for name in ("means", "log_scales", "quats", "opacity_logits")
    }
    expected = {
        "means": base["means"] + d.dxyz,
        "log_scales": base["log_scales"] + d.dscale,
        "quats": base["quats"] + d.drot,
        "opacity_logits": base["opacity_logits"] + d.dopacity[:, 0],
    }
    for name, values in expected.items():
        got = torch.cat([getattr(part, name) for part in parts]).detach()
        torch.testing.assert_close(got, values, msg=name)


SPY_WEIGHTS = {"plane_smoothness": 0.5, "time_smoothness": 2.0, "time_l1": 3.0}
SPY_STEPS = 4


@pytest.fixture(scope="module")
def deform_spy(stage_scene: Scene, stage_relayed: Artifact) -> SimpleNamespace:
    """A 4-step deform run (2 frames a step) with large regulariser weights, recorded."""
    # per step: the loss returned, its photometric part and regularisers; per field evaluation:
    # the frame's views and the time
    spy = SimpleNamespace(losses=[], photometric=[], regularisers=[], frame_views=[], times=[])
    real_run_training = deform_module.run_training
    real_photometric = deform_module.photometric_loss
    real_deformed_parts = deform_module.deformed_parts
    real_regularisers = DeformationField.regularisers

    class RecordingViews(TrainViews):
        def random_views_at(self, frame: int, count: int, generator: Any) -> list[View]:
            views = super().random_views_at(frame, count, generator)
            spy.frame_views.append(views)
            return views

    def run_training(stage: str, session: Any, steps: int, train: Any, step_fn: Any, counts: Any):
        def recorded_step(step: int) -> Any:
            result = step_fn(step)
            spy.losses.append(result.loss.detach().clone())
            return result

        return real_run_training(stage, session, steps, train, recorded_step, counts)

    def photometric_loss(*args: Any, **kwargs: Any) -> torch.Tensor:
        loss = real_photometric(*args, **kwargs)
        spy.photometric.append(loss.detach().clone())
        return loss

    def deformed_parts(*args: Any, **kwargs: Any) -> Any:
        spy.times.append(args[4])
        return real_deformed_parts(*args, **kwargs)

    def regularisers(self: DeformationField) -> dict[str, torch.Tensor]:
        values = real_regularisers(self)
        spy.regularisers.append({name: value.detach().clone() for name, value in values.items()})
        return values

    cfg = stage_smoke_cfg(deform={"steps": SPY_STEPS, "frames_per_step": 2, **SPY_WEIGHTS})
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(deform_module, "TrainViews", RecordingViews)
        patch.setattr(deform_module, "run_training", run_training)
        patch.setattr(deform_module, "photometric_loss", photometric_loss)
        patch.setattr(deform_module, "deformed_parts", deformed_parts)
        patch.setattr(DeformationField, "regularisers", regularisers)
        SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg)
    return spy


def test_step_loss_and_the_time_of_each_training_frame(
    deform_spy: SimpleNamespace, stage_scene: Scene
) -> None:
    """Each step's loss is photometric plus the weighted plane regularisers; a training frame's
    time is frame / (T − 1), the time its views carry and evaluation renders it at."""
    spy = deform_spy
    assert len(spy.losses) == len(spy.photometric) == len(spy.regularisers) == SPY_STEPS
    for loss, photometric, values in zip(
        spy.losses, spy.photometric, spy.regularisers, strict=True
    ):
        assert set(values) == set(SPY_WEIGHTS)
        penalty = sum(weight * values[name] for name, weight in SPY_WEIGHTS.items())
        assert float(penalty) > 1e-3  # large enough to tell a loss without it apart
        torch.testing.assert_close(loss, photometric + penalty)
    assert len(spy.times) == len(spy.frame_views) == 2 * SPY_STEPS
    last = stage_scene.num_frames - 1
    frames = set()
    for time, views in zip(spy.times, spy.frame_views, strict=True):
        frame = views[0].frame
        frames.add(frame)
        assert all(view.frame == frame for view in views)
        assert time == pytest.approx(frame / last)
        assert all(view.time == pytest.approx(time) for view in views)
    assert frames - {0}  # a frame > 0 was drawn: frame / T would differ there
