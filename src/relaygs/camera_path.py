"""An orbit around a scene's centre at its cameras' mean height and distance, each view looking
at the centre with the first camera's intrinsics: a full circle from the first camera's azimuth
when the cameras surround the centre, else an arc over their azimuths (where they saw it)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import pairwise

import torch
from torch import Tensor

from relaygs.data import Camera
from relaygs.errors import InputError

OPEN_GAP = math.radians(100)  # a wider azimuth gap: the cameras do not surround the scene
PATH_CAMERA_ID = -1  # no scene camera has it, so no training camera's colour affine applies
MIN_RADIUS = 1e-6  # below this fraction of their distance, the cameras are on the axis
PARALLEL_SPREAD = 1e-4  # x axes this close to one direction (per camera): no common up


def path_cameras(cameras: Sequence[Camera], count: int, centre: Tensor) -> list[Camera]:
    """`count` views evenly spaced along the orbit that `cameras` place around `centre` [3]; a
    full circle does not repeat its first view at the end, so its video repeats seamlessly."""
    if count < 1:
        raise InputError(f"camera path: expected at least 1 view, got {count}")
    if not cameras:
        raise InputError("camera path: no cameras to go round")
    centre = centre.to(torch.float64)
    up = _up(cameras)
    offsets = torch.stack([camera.center.to(torch.float64) for camera in cameras]) - centre
    heights = offsets @ up
    flat = offsets - heights[:, None] * up  # in the plane at right angles to `up`
    radii = flat.norm(dim=1)
    radius = float(radii.mean())
    if radius <= MIN_RADIUS * float(offsets.norm(dim=1).mean()):
        raise InputError(
            "camera path: the cameras sit on the vertical through the scene's centre; "
            "there is no orbit round it"
        )
    e1 = _unit(flat[int(radii.argmax())], fallback=_perpendicular(up))
    e2 = torch.linalg.cross(up, e1)
    start, span, closed = _azimuth_range(torch.atan2(flat @ e2, flat @ e1))
    steps = count if closed else max(count - 1, 1)
    axis_point = centre + float(heights.mean()) * up  # the orbit's own centre, level with it
    path = []
    for view in range(count):
        angle = start + span * view / steps
        eye = axis_point + radius * (math.cos(angle) * e1 + math.sin(angle) * e2)
        path.append(_looking_at(eye, centre, up, cameras[0]))
    return path


def _up(cameras: Sequence[Camera]) -> Tensor:
    """The direction at right angles to every camera's x axis (level cameras' x axes are
    horizontal), along their mean up, which it is when the x axes are parallel."""
    c2ws = [camera.c2w.to(torch.float64) for camera in cameras]
    downs = torch.stack([c2w[:3, 1] for c2w in c2ws])  # OpenCV: a camera's y axis points down
    mean_up = _unit(-downs.sum(dim=0), fallback=-downs[0])
    rights = torch.stack([c2w[:3, 0] for c2w in c2ws])
    spread, axes = torch.linalg.eigh(rights.T @ rights)  # ascending
    if float(spread[1]) <= PARALLEL_SPREAD * len(cameras):
        return mean_up
    up = axes[:, 0]
    return up if float(up @ mean_up) >= 0 else -up


def _azimuth_range(angles: Tensor) -> tuple[float, float, bool]:
    """(start, span, closed) over azimuths `angles`: the circle from the first camera's when no
    gap between neighbours exceeds OPEN_GAP, else the arc that leaves out the widest gap."""
    first = float(angles[0])
    ordered = sorted(float(angle) % (2 * math.pi) for angle in angles)
    gaps = [b - a for a, b in pairwise(ordered)]
    gaps.append(ordered[0] + 2 * math.pi - ordered[-1])
    widest = max(range(len(gaps)), key=gaps.__getitem__)
    if len(ordered) > 1 and gaps[widest] <= OPEN_GAP:
        return first, 2 * math.pi, True
    return ordered[(widest + 1) % len(ordered)], 2 * math.pi - gaps[widest], False


def _looking_at(eye: Tensor, target: Tensor, up: Tensor, reference: Camera) -> Camera:
    """A camera at `eye` looking at `target`, `up` up, with `reference`'s intrinsics."""
    forward = _unit(target - eye, fallback=-up)
    right = _unit(torch.linalg.cross(forward, up), fallback=_perpendicular(forward))
    down = torch.linalg.cross(forward, right)
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = torch.stack([right, down, forward])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return Camera(
        PATH_CAMERA_ID,
        reference.K.clone(),
        w2c.to(reference.w2c.dtype),
        reference.width,
        reference.height,
        reference.near,
    )


def _unit(vector: Tensor, fallback: Tensor) -> Tensor:
    length = float(vector.norm())
    if length > 1e-9:
        return vector / length
    return fallback / fallback.norm()


def _perpendicular(axis: Tensor) -> Tensor:
    helper = torch.zeros_like(axis)
    helper[int(axis.abs().argmin())] = 1.0
    return _unit(torch.linalg.cross(axis, helper), fallback=helper)
