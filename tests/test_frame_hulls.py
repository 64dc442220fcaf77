"""Each frame's visual hull as a target of the deformed foreground (deform.hull_weight)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from conftest import STAGE_K, stage_smoke_cfg
from relaygs.data import Scene, frame_time
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import SPECS, SceneModel
from relaygs.stages.carve import HullSettings, relay_hull_settings
from relaygs.stages.deform import DeformConfig, _starting_model
from relaygs.stages.frame_hulls import FrameHulls, distance_beyond
from relaygs.stages.hull_prefit import prefit_foreground_motion
from relaygs.train.motion import deformed_parts
from relaygs.train.views import TrainViews


def test_distance_beyond_counts_only_the_excess_and_has_no_gradient_inside() -> None:
    offsets = torch.tensor([[0.0, 0.0, 0.5], [3.0, 4.0, 0.0], [0.0, 0.0, 0.0]], requires_grad=True)
    value = distance_beyond(offsets, 1.0)
    value.backward()
    assert float(value.detach()) == pytest.approx(4.0 / 3.0)
    expected = torch.tensor([[0.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 0.0]]) / 3.0
    assert torch.allclose(offsets.grad, expected)


def test_a_frame_pulls_outside_means_in_and_coverage_pulls_the_nearest_to_an_empty_part() -> None:
    hull = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [5.0, 0.0, 0.0]])
    hulls = FrameHulls({3: hull}, {3: 0.2})
    means = torch.tensor([[0.05, 0.0, 0.0], [0.0, 2.0, 0.0]], requires_grad=True)
    one_sided = hulls.distance(means, 3)
    assert float(one_sided.detach()) == pytest.approx((2.0 - 0.2) / 2, rel=1e-5)
    (grad,) = torch.autograd.grad(one_sided, means)
    assert torch.equal(grad[0], torch.zeros(3))  # inside: no pull
    assert torch.allclose(grad[1], torch.tensor([0.0, 0.5, 0.0]))  # away from the hull
    # the hull point at x = 5 is nearest to the first mean: coverage drags that one along +x
    (grad,) = torch.autograd.grad(hulls.distance(means, 3, coverage=1.0), means)
    assert float(grad[0, 0]) < 0.0 and float(grad[1, 0]) == 0.0
    assert float(hulls.distance(means, 4)) == 0.0  # a frame without a hull
    assert float(hulls.distance(means[:0], 3)) == 0.0  # no Gaussians shown


def _carved(
    scene: Scene, artifact: Artifact, relay_keys: dict | None = None
) -> tuple[SceneModel, TrainViews, FrameHulls]:
    """The artifact's model, the scene's train views and the hulls carved from that model."""
    model = SceneModel.from_artifact(artifact)
    views = TrainViews(scene, torch.device("cpu"))
    return model, views, FrameHulls.carve(views, model.background, model.blur(), 0, relay_keys)


def test_each_frames_hull_lies_in_that_frames_foreground(
    stage_scene: Scene, stage_decoupled: Artifact
) -> None:
    _, views, hulls = _carved(stage_scene, stage_decoupled)
    assert sorted(hulls.points) == list(range(stage_scene.num_frames))
    for frame, points in hulls.points.items():
        inside = []
        for view in views.by_frame[frame]:
            mask = stage_scene.mask(view)
            dilated = F.max_pool2d(mask[None, None].float(), 3, stride=1, padding=1)[0, 0] > 0
            pixels, visible = view.camera.project(points, min_depth=view.camera.near)
            column = pixels[:, 0].floor().long().clamp(0, view.camera.width - 1)
            row = pixels[:, 1].floor().long().clamp(0, view.camera.height - 1)
            inside.append(dilated[row, column][visible].float().mean())
        assert float(torch.stack(inside).mean()) > 0.8, frame


def _shown_hull_distance(
    model: SceneModel, scene: Scene, hulls: FrameHulls, coverage: float = 0.0
) -> float:
    total = 0.0
    with torch.no_grad():
        for frame in range(scene.num_frames):
            rows = model.foreground_rows(frame)
            time = frame_time(frame, scene.num_frames)
            parts = deformed_parts(model.background, model.foreground, rows, model.field, time, 0)
            total += float(hulls.distance(parts[1].means, frame, coverage))
    return total


def test_the_hull_term_draws_the_shown_copies_into_their_frames_hulls(
    stage_scene: Scene, stage_decoupled: Artifact, stage_relayed: Artifact
) -> None:
    _, _, hulls = _carved(stage_scene, stage_relayed)
    fixed = {"densify_until": 0, "opacity_reset_every": 0}  # the same Gaussians throughout
    distances = {}
    for weight in (0.0, 10.0):
        section = {"steps": 60, "hull_weight": weight, "lr_fg": {"means": 0.02}}
        cfg = stage_smoke_cfg(deform={**section, "densify_fg": fixed, "densify_bg": fixed})
        artifact = SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg)
        distances[weight] = _shown_hull_distance(
            SceneModel.from_artifact(artifact), stage_scene, hulls
        )
    assert STAGE_K > 1  # each copy spans several frames, whose hulls it cannot all fill
    assert distances[10.0] < 0.95 * distances[0.0]


def test_relay_hull_keys_map_to_settings_and_missing_keys_keep_defaults() -> None:
    keys = {"hull_residual": 0.3, "hull_voxels": 24, "hull_misses": 0.05, "hull_seen": 0.75}
    settings = relay_hull_settings(keys, target_points=100)
    assert settings == HullSettings(0.3, 24, 0.05, 0.75, 100)
    assert relay_hull_settings({}, None) == HullSettings()


def test_deform_carves_its_hulls_with_the_relays_own_hull_keys(
    stage_scene: Scene, stage_relayed: Artifact, monkeypatch: pytest.MonkeyPatch
) -> None:
    echo = stage_relayed.meta["config"]["section"]
    strict = {**echo, "hull_residual": 0.6}
    default_points = _carved(stage_scene, stage_relayed, echo)[2].points
    strict_points = _carved(stage_scene, stage_relayed, strict)[2].points
    assert sum(map(len, strict_points.values())) < sum(map(len, default_points.values()))

    seen = []

    class HullsCarvedError(Exception):
        """Stops the deform stage once its hulls are carved: the keys are all this test needs."""

    def spy(*args: object) -> FrameHulls:
        seen.append(args[-1])
        raise HullsCarvedError

    monkeypatch.setattr(FrameHulls, "carve", spy)
    cfg = stage_smoke_cfg(deform={"steps": 1, "hull_weight": 1.0})
    with pytest.raises(HullsCarvedError):
        SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg)
    assert seen == [echo]


def test_the_prefit_moves_the_shown_copies_into_their_hulls_and_leaves_the_rest(
    stage_scene: Scene, stage_relayed: Artifact
) -> None:
    relayed, _, hulls = _carved(stage_scene, stage_relayed)
    section = DeformConfig.from_config({"steps": 10})
    model = _starting_model(relayed, section, stage_scene, 0, relayed.blur())
    gaussians = {name: p.detach().clone() for name, p in model.foreground.params.items()}
    rates = {"grid": 6.4e-3, "mlp": 6.4e-4}
    weights = {"plane_smoothness": 2e-4, "time_smoothness": 1e-3, "time_l1": 1e-4}

    def shown_distance() -> float:
        return _shown_hull_distance(model, stage_scene, hulls, coverage=1.0)

    before = shown_distance()
    prefit_foreground_motion(model, hulls, 50, rates, weights, 1.0, stage_scene.extent, seed=0)
    assert shown_distance() < 0.8 * before
    for name, param in model.foreground.params.items():
        assert torch.equal(param, gaussians[name]) and param.grad is None, name
    with torch.no_grad():
        still = model.field(model.background.means, 0.5, len(model.background))
    assert torch.equal(still.dxyz, torch.zeros_like(still.dxyz))  # its MLP set is untouched
