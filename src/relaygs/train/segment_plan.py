"""Where the relay stage's segments start: k frames each (the paper's), or placed so that each
holds an equal share of the scene's frame-to-frame motion (short where it moves fast)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from relaygs.data import Scene
from relaygs.errors import InputError

MOTION_CAMERAS = 8  # train cameras, spread over the rig, whose image changes measure motion


@dataclass(frozen=True)
class SegmentPlan:
    """Segment s covers frames [starts[s], starts[s+1]) (the last runs to num_frames)."""

    starts: tuple[int, ...]
    num_frames: int

    def __post_init__(self) -> None:
        """Starts begin at frame 0 and increase strictly inside the scene."""
        starts = list(self.starts)
        if not starts or starts[0] != 0 or starts != sorted(set(starts)):
            raise InputError(f"segment starts: expected 0 first and increasing, got {starts}")
        if starts[-1] >= self.num_frames:
            raise InputError(f"segment starts: {starts[-1]} is past frame {self.num_frames - 1}")

    @classmethod
    def uniform(cls, num_frames: int, k: int) -> SegmentPlan:
        """ceil(T / k) segments of k frames, the last one shorter where k does not divide T."""
        return cls(tuple(range(0, num_frames, k)), num_frames)

    @classmethod
    def by_motion(cls, motion: Tensor, segments: int) -> SegmentPlan:
        """`segments` segments over len(motion) + 1 frames, holding equal shares of motion."""
        num_frames = motion.numel() + 1
        if not 1 <= segments <= num_frames:
            raise InputError(f"relay.k: expected 1..{num_frames} segments, got {segments}")
        # a floor spreads boundaries evenly through stretches with no motion at all
        steps = motion.double().clamp_min(0.0) + 1e-6 * float(motion.double().abs().mean() + 1e-9)
        cumulative = torch.cat([steps.new_zeros(1), steps.cumsum(0)]).tolist()
        starts = [0]
        for share in range(1, segments):
            wanted = cumulative[-1] * share / segments
            # the first frame whose cumulative motion reaches the share, at least one frame
            # after the previous start and leaving a frame for each later segment
            frame = bisect.bisect_left(cumulative, wanted)
            frame = min(max(frame, starts[-1] + 1), num_frames - (segments - share))
            starts.append(frame)
        return cls(tuple(starts), num_frames)

    @property
    def count(self) -> int:
        return len(self.starts)

    def frames(self, segment: int) -> range:
        """The frames of segment s."""
        end = self.starts[segment + 1] if segment + 1 < self.count else self.num_frames
        return range(self.starts[segment], end)

    def segment_of(self, frame: int) -> int:
        """The segment holding `frame` (frames past the end belong to the last)."""
        return bisect.bisect_right(self.starts, min(frame, self.num_frames - 1)) - 1

    @property
    def uniform_length(self) -> int | None:
        """k when the plan is the uniform k-frame one, else None."""
        k = self.starts[1] if self.count > 1 else self.num_frames
        return k if self == SegmentPlan.uniform(self.num_frames, k) else None

    def lengths(self) -> list[int]:
        return [len(self.frames(segment)) for segment in range(self.count)]


def boundaries_fixed(num_frames: int, k: int) -> bool:
    """Whether S = ceil(T / k) segments leave no choice of boundaries (one frame each, or one
    segment of all frames): adaptive placement then is the uniform plan."""
    return math.ceil(num_frames / k) in (1, num_frames)


def frame_motion(scene: Scene, cameras: int = MOTION_CAMERAS) -> Tensor:
    """Mean absolute image change between consecutive frames [T - 1] over up to `cameras` train
    cameras, less its smallest value (what sensor noise alone gives the stillest pair)."""
    camera_ids = sorted({view.camera.camera_id for view in scene.train_views})
    if len(camera_ids) > cameras:  # spread evenly over the rig
        camera_ids = [camera_ids[math.floor(i * len(camera_ids) / cameras)] for i in range(cameras)]
    by_key = {(view.frame, view.camera.camera_id): view for view in scene.train_views}
    totals = torch.zeros(max(scene.num_frames - 1, 0), dtype=torch.float64)
    counts = torch.zeros_like(totals)
    for camera in camera_ids:
        previous = None
        for frame in range(scene.num_frames):
            view = by_key.get((frame, camera))
            image = scene.image(view) if view is not None else None
            if image is not None and previous is not None and previous[0] == frame - 1:
                totals[frame - 1] += float((image - previous[1]).abs().mean())
                counts[frame - 1] += 1
            previous = (frame, image) if image is not None else None
    change = totals / counts.clamp_min(1)
    return change - change.min() if change.numel() else change
