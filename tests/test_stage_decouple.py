"""Decouple (and the static warm-up): straight-through mask, well-formed output, separation."""

from __future__ import annotations

import torch

from conftest import stage_smoke_cfg
from relaygs.data import Scene
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import STAGES, SceneModel
from relaygs.stages.decouple import straight_through_mask

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


def test_output_is_finite_and_well_formed(stage_decoupled: Artifact, stage_scene: Scene) -> None:
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
    assert (
        stage_decoupled.meta["metrics"]["final_loss"]
        < stage_decoupled.meta["metrics"]["initial_loss"]
    )


def test_foreground_is_shown_only_at_frame_zero(stage_decoupled: Artifact) -> None:
    model = SceneModel.from_artifact(stage_decoupled)
    assert model.foreground_rows(0).numel() == len(model.foreground)
    assert model.foreground_rows(3).numel() == 0


def test_movers_are_foreground_and_static_parts_background(
    stage_decoupled: Artifact, stage_scene: Scene
) -> None:
    model = SceneModel.from_artifact(stage_decoupled)
    means = torch.cat([model.background.means, model.foreground.means]).detach()
    nearest = torch.cdist(stage_scene.points.xyz, means).argmin(dim=1)
    marked_fg = stage_decoupled.tensors["is_fg"][nearest]
    on_mover = stage_scene.points.is_fg
    assert on_mover.any() and (~on_mover).any()
    assert marked_fg[on_mover].float().mean() >= MOVER_MARKED_FG
    assert (~marked_fg[~on_mover]).float().mean() >= STATIC_MARKED_BG


def test_warmup_is_all_background(stage_scene: Scene) -> None:
    artifact = STAGES["warmup"](stage_scene, {}, stage_smoke_cfg())
    assert artifact.stage == "warmup"
    assert artifact.meta["counts"]["fg"] == 0
    assert not artifact.tensors["is_fg"].any()
    assert (artifact.tensors["segment"] == -1).all()
    assert torch.isfinite(artifact.tensors["bg.means"]).all()
    # the smoke budget densifies and prunes: the count moved off the initial 1500
    assert artifact.meta["counts"]["bg"] != 1500
