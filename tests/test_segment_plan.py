"""Segment plans: uniform k-frame segments and motion-adaptive ones."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from relaygs.errors import InputError
from relaygs.stages.segment_plan import SegmentPlan, frame_motion
from relaygs.stages.segments import num_segments, segment_frames


@pytest.mark.parametrize(("num_frames", "k"), [(64, 1), (64, 16), (10, 4), (7, 7), (5, 9)])
def test_uniform_plan_is_the_k_frame_segments(num_frames, k):
    plan = SegmentPlan.uniform(num_frames, k)
    assert plan.count == num_segments(num_frames, k)
    for segment in range(plan.count):
        assert plan.frames(segment) == segment_frames(segment, k, num_frames)
        assert all(plan.segment_of(frame) == segment for frame in plan.frames(segment))
    assert plan.segment_of(num_frames + 3) == plan.count - 1


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


def test_without_motion_segments_are_even_and_every_frame_is_covered():
    plan = SegmentPlan.by_motion(torch.zeros(15), segments=4)
    assert plan.lengths() == [4, 4, 4, 4]
    crowded = SegmentPlan.by_motion(torch.tensor([0.0] * 6 + [5.0]), segments=8)
    assert crowded.lengths() == [1] * 8  # as many segments as frames: one frame each


@pytest.mark.parametrize("segments", [0, 9])
def test_a_segment_budget_outside_the_frames_is_refused(segments):
    with pytest.raises(InputError, match=r"relay\.copies"):
        SegmentPlan.by_motion(torch.ones(7), segments)


@pytest.mark.parametrize("starts", [(), (1, 3), (0, 3, 3), (0, 8)])
def test_malformed_starts_are_refused(starts):
    with pytest.raises(InputError):
        SegmentPlan(starts, num_frames=8)
