"""Relay and replicate: segments, pseudo-view targets, frozen background, copies per segment."""

from __future__ import annotations

import math

import pytest
import torch

from conftest import STAGE_K, stage_smoke_cfg
from refusals import refused
from relaygs.data import Scene, load_scene
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import SPECS, SceneModel
from relaygs.train.segment_plan import SegmentPlan
from relaygs.train.segments import SegmentTargets, pseudo_frames
from relaygs.train.views import TrainViews, views_per_slot


@pytest.mark.parametrize(
    ("segment", "k", "num_frames", "p", "expected"),
    [
        (0, 16, 64, 3, [0, 8, 15]),  # first, middle, last
        (3, 16, 64, 3, [48, 56, 63]),
        (1, 4, 6, 3, [4, 5]),  # a short last segment gives fewer frames
        (0, 1, 5, 3, [0]),
        (2, 10, 30, 1, [24]),
        (0, 9, 9, 5, [0, 2, 4, 6, 8]),
    ],
)
def test_pseudo_frames_spread_over_the_segment(
    segment: int, k: int, num_frames: int, p: int, expected: list[int]
) -> None:
    assert pseudo_frames(SegmentPlan.uniform(num_frames, k).frames(segment), p) == expected


def test_targets_are_the_pseudo_view_blends_or_single_frames(stage_scene: Scene) -> None:
    views = TrainViews(stage_scene, torch.device("cpu"))
    camera = stage_scene.train_cameras[2].camera_id
    generator = torch.Generator().manual_seed(0)
    plan = SegmentPlan.uniform(stage_scene.num_frames, STAGE_K)
    targets = SegmentTargets(views, plan, p=3, pseudo_views=True)
    for segment in range(2):
        first = segment * STAGE_K
        frames = (first, first + 2, first + STAGE_K - 1)  # linspace(first, last, 3), rounded
        images = [stage_scene.image(views.view(frame, camera)) for frame in frames]
        expected = (images[0] + images[1] + images[2]) / 3
        torch.testing.assert_close(targets.target(camera, segment, generator), expected)
        assert not torch.equal(images[0], images[2])  # the blend really mixes moving content
    targets = SegmentTargets(views, plan, p=3, pseudo_views=False)
    segment_images = [stage_scene.image(views.view(f, camera)) for f in range(STAGE_K, 2 * STAGE_K)]
    for _ in range(6):
        target = targets.target(camera, 1, generator)
        assert any(torch.equal(target, image) for image in segment_images)


def test_relay_output(stage_relayed: Artifact, stage_decoupled: Artifact, stage_scene: Scene):
    tensors, meta = stage_relayed.tensors, stage_relayed.meta
    segments = math.ceil(stage_scene.num_frames / STAGE_K)
    assert (meta["k"], meta["num_segments"]) == (STAGE_K, segments)
    for name, tensor in tensors.items():
        if name.startswith("bg."):  # frozen background: bit-identical to the upstream one
            assert torch.equal(tensor, stage_decoupled.tensors[name]), name
        if tensor.is_floating_point():
            assert torch.isfinite(tensor).all(), name
    segment = tensors["segment"]
    assert int(segment.min()) >= -1 and int(segment.max()) <= segments - 1
    assert torch.equal(segment == -1, ~tensors["is_fg"])
    per_segment = torch.bincount(tensors["fg.buffer.segment"].long(), minlength=segments)
    assert (per_segment > 0).all()
    assert per_segment.tolist() == meta["metrics"]["fg_per_segment"]
    model = SceneModel.from_artifact(stage_relayed)  # each frame shows its segment's copy
    segments = model.foreground.buffers["segment"]
    for frame in range(model.num_frames):
        rows = model.foreground_rows(frame)
        assert rows.numel() > 0
        assert (segments[rows] == frame // STAGE_K).all()


def test_replicate_copies_the_foreground_untrained(
    stage_scene: Scene, stage_decoupled: Artifact
) -> None:
    replicated = SPECS["replicate"].run(
        stage_scene, {"decouple": stage_decoupled}, stage_smoke_cfg()
    )
    n_fg = stage_decoupled.meta["counts"]["fg"]
    assert replicated.meta["counts"]["fg"] == 2 * n_fg
    for copy in range(2):
        rows = slice(copy * n_fg, (copy + 1) * n_fg)
        assert torch.equal(
            replicated.tensors["fg.means"][rows], stage_decoupled.tensors["fg.means"]
        )
        assert (replicated.tensors["fg.buffer.segment"][rows] == copy).all()
    assert torch.equal(replicated.tensors["bg.sh_dc"], stage_decoupled.tensors["bg.sh_dc"])


def test_one_frame_segments_give_a_copy_per_frame(
    stage_scene: Scene, stage_decoupled: Artifact
) -> None:
    """k = 1 (the `small` budget's setting): S = T copies, each frame shows its own, and the
    pseudo-view of a one-frame segment is that frame's image, with or without blending."""
    cfg = stage_smoke_cfg(relay={"steps": 3, "k": 1, "pseudo_views": False})
    relayed = SPECS["relay"].run(stage_scene, {"decouple": stage_decoupled}, cfg)
    assert relayed.meta["config"]["section"]["pseudo_views"] is False
    assert torch.isfinite(relayed.tensors["fg.means"]).all()
    frames = stage_scene.num_frames
    assert (relayed.meta["k"], relayed.meta["num_segments"]) == (1, frames)
    model = SceneModel.from_artifact(relayed)
    for frame in range(frames):
        rows = model.foreground_rows(frame)
        assert rows.numel() > 0
        assert (model.foreground.buffers["segment"][rows] == frame).all()
    views = TrainViews(stage_scene, torch.device("cpu"))
    camera = stage_scene.train_cameras[1].camera_id
    generator = torch.Generator().manual_seed(0)
    blended = SegmentTargets(views, SegmentPlan.uniform(frames, 1), p=3, pseudo_views=True)
    single = SegmentTargets(views, SegmentPlan.uniform(frames, 1), p=3, pseudo_views=False)
    for frame in (0, frames - 1):
        image = stage_scene.image(views.view(frame, camera))
        assert torch.equal(blended.target(camera, frame, generator), image)
        assert torch.equal(single.target(camera, frame, generator), image)


@pytest.mark.parametrize("segments_per_step", [1, 4])
def test_a_step_fits_only_the_copies_of_the_segments_it_drew(
    segments_per_step: int, stage_scene: Scene, stage_decoupled: Artifact
) -> None:
    """Replicated (identical) copies of one-frame segments, one relay step: the step renders
    and fits only the copies of the segments it drew (one, or up to one per view), so those
    move and every other stays bit-identical; a background not frozen trains too."""
    relay = {"steps": 1, "k": 1, "seed_copies": "replicate", "freeze_background": False}
    cfg = stage_smoke_cfg(relay={**relay, "segments_per_step": segments_per_step})
    relayed = SPECS["relay"].run(stage_scene, {"decouple": stage_decoupled}, cfg)
    assert not torch.equal(relayed.tensors["bg.means"], stage_decoupled.tensors["bg.means"])
    segment = relayed.tensors["fg.buffer.segment"]
    upstream = {
        name: tensor
        for name, tensor in stage_decoupled.tensors.items()
        if name.startswith("fg.") and tensor.is_floating_point()
    }
    assert "fg.means" in upstream
    changed = []
    for copy in range(stage_scene.num_frames):
        rows = segment == copy
        assert int(rows.sum()) == stage_decoupled.meta["counts"]["fg"]
        changed.append(
            any(not torch.equal(relayed.tensors[name][rows], up) for name, up in upstream.items())
        )
    if segments_per_step == 1:
        assert sum(changed) == 1
    else:  # four draws among eight segments: seed 0 draws more than one
        assert 2 <= sum(changed) <= segments_per_step


def test_a_batch_splits_round_robin_among_its_frames_or_segments() -> None:
    assert views_per_slot(4, 1) == [4]
    assert views_per_slot(4, 3) == [2, 1, 1]
    assert views_per_slot(4, 4) == [1, 1, 1, 1]
    assert views_per_slot(2, 4) == [1, 1]  # slots beyond the views get none


def test_draws_at_a_frame_take_every_camera_once_before_repeating_one(stage_scene: Scene) -> None:
    views = TrainViews(stage_scene, torch.device("cpu"))
    cameras = {view.camera.camera_id for view in views.by_frame[3]}
    drawn = views.random_views_at(3, len(cameras) + 5, torch.Generator().manual_seed(0))
    assert len(drawn) == len(cameras) + 5 and {view.frame for view in drawn} == {3}
    assert sorted(view.camera.camera_id for view in drawn[: len(cameras)]) == sorted(cameras)
    with pytest.raises(InputError, match="camera 999 has no train image at frame 0"):
        views.view(0, 999)
    frame = stage_scene.num_frames
    with pytest.raises(InputError, match=f"no train views at frame {frame}"):
        views.random_views_at(frame, 1, torch.Generator().manual_seed(0))


def test_stages_refuse_upstreams_they_cannot_use(
    stage_scene: Scene, stage_decoupled: Artifact, tiny_synth_scene
) -> None:
    with refused(InputError, "'relay'", "upstream must be one of"):
        SPECS["relay"].run(stage_scene, {"x": Artifact("warmup")}, stage_smoke_cfg())
    with refused(InputError, "'relay'", "exactly one upstream"):
        SPECS["relay"].run(stage_scene, {}, stage_smoke_cfg())
    with refused(InputError, "'decouple'", "['x']"):
        SPECS["decouple"].run(stage_scene, {"x": stage_decoupled}, stage_smoke_cfg())
    other = load_scene(tiny_synth_scene)  # 6 frames, the upstream 8
    with refused(InputError, "'decouple'", "8 frames", "6"):
        SPECS["relay"].run(other, {"decouple": stage_decoupled}, stage_smoke_cfg())
