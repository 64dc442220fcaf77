"""Segment plans: uniform k-frame segments and motion-adaptive ones."""

from types import SimpleNamespace

import pytest
import torch

from conftest import stage_smoke_cfg
from relaygs.errors import InputError
from relaygs.stages import SPECS, SceneModel
from relaygs.train.canonical import uniform_unless_adaptive
from relaygs.train.segment_plan import SegmentPlan, frame_motion


@pytest.mark.parametrize(
    ("num_frames", "k", "count"),
    [(70, 16, 5), (64, 16, 4), (64, 1, 64), (1, 16, 1), (17, 16, 2), (7, 7, 1), (5, 9, 1)],
)
def test_uniform_plan_is_ceil_t_over_k_segments_of_k_frames(num_frames, k, count):
    plan = SegmentPlan.uniform(num_frames, k)
    assert plan.count == count and plan.uniform_length == min(k, num_frames)
    covered = [frame for segment in range(count) for frame in plan.frames(segment)]
    assert covered == list(range(num_frames))  # every frame once, the last segment shorter
    for segment in range(count):
        assert plan.frames(segment) == range(segment * k, min((segment + 1) * k, num_frames))
        assert all(plan.segment_of(frame) == segment for frame in plan.frames(segment))
    assert plan.segment_of(num_frames + 3) == count - 1


def _still_then_fast_scene(num_frames: int = 32, cameras: int = 3) -> SimpleNamespace:
    """A bright square that stands still for the first half and moves 3 px a frame after."""
    images = {}
    for frame in range(num_frames):
        x = 2 + 3 * max(0, frame - num_frames // 2)
        image = torch.zeros(12, 64, 3)
        image[4:8, x : x + 4] = 1.0
        images[frame] = image
    views = [
        SimpleNamespace(frame=frame, camera=SimpleNamespace(camera_id=camera))
        for camera in range(cameras)
        for frame in range(num_frames)
    ]
    return SimpleNamespace(
        num_frames=num_frames, train_views=views, image=lambda view: images[view.frame]
    )


def test_boundaries_follow_the_motion():
    scene = _still_then_fast_scene()
    motion = frame_motion(scene)
    assert motion.shape == (31,)
    assert float(motion[:15].abs().max()) == 0.0 and bool((motion[16:] > 0).all())
    plan = SegmentPlan.by_motion(motion, segments=4)  # S = T / 8
    assert plan.starts[0] == 0 and plan.count == 4
    assert all(start >= 16 for start in plan.starts[1:])  # every boundary in the fast half
    assert plan.lengths()[0] >= 16  # the still half is one long segment
    assert plan.uniform_length is None


def test_without_motion_segments_are_even_and_every_frame_is_covered():
    plan = SegmentPlan.by_motion(torch.zeros(15), segments=4)
    assert plan.lengths() == [4, 4, 4, 4]
    crowded = SegmentPlan.by_motion(torch.tensor([0.0] * 6 + [5.0]), segments=8)
    assert crowded.lengths() == [1] * 8  # as many segments as frames: one frame each


@pytest.mark.parametrize("segments", [0, 9])
def test_a_segment_budget_outside_the_frames_is_refused(segments):
    with pytest.raises(InputError, match=r"relay\.k"):
        SegmentPlan.by_motion(torch.ones(7), segments)


@pytest.mark.parametrize("starts", [(), (1, 3), (0, 3, 3), (0, 8)])
def test_malformed_starts_are_refused(starts):
    with pytest.raises(InputError):
        SegmentPlan(starts, num_frames=8)


def test_an_adaptive_relay_keeps_its_segments_through_the_artifact(stage_scene, stage_decoupled):
    cfg = stage_smoke_cfg(relay={"k": 2, "segments": "adaptive", "seed_copies": "replicate"})
    relayed = SPECS["relay"].run(stage_scene, {"decouple": stage_decoupled}, cfg)
    expected = SegmentPlan.by_motion(frame_motion(stage_scene), 4)  # S = ceil(8 / 2)
    assert relayed.meta["segment_starts"] == list(expected.starts)
    assert relayed.meta["metrics"]["segment_lengths"] == expected.lengths()
    model = SceneModel.from_artifact(relayed)
    assert model.segments == expected
    for frame in range(stage_scene.num_frames):
        rows = model.foreground_rows(frame)
        assert (model.foreground.buffers["segment"][rows] == expected.segment_of(frame)).all()


@pytest.mark.parametrize(
    ("section", "kept"),
    [
        ({"k": 4}, False),
        ({"k": 4, "segments": "uniform"}, False),  # the key of a uniform relay is unchanged
        ({"k": 1, "segments": "adaptive"}, False),  # one frame a segment either way
        ({"k": 99, "segments": "adaptive"}, False),  # one segment either way
        ({"k": 4, "segments": "adaptive"}, True),
    ],
)
def test_segments_enter_the_key_only_where_they_change_the_run(section, kept):
    canonical = uniform_unless_adaptive(section, SimpleNamespace(num_frames=64))
    assert ("segments" in canonical) == kept
