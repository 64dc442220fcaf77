"""A camera path through a scene's cameras, to see a model from between the captured views.

The cameras are ordered by azimuth around the scene's centre, about the mean of their up
directions. The path closes into a loop when they surround the centre and runs from one end
to the other when they do not (when two neighbours are more than OPEN_GAP apart). Poses in
between are interpolated: camera centres linearly, orientations by quaternion slerp. Every
camera on the path has the intrinsics, image size and near plane of the first camera given.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import pairwise

import torch
from torch import Tensor

from relaygs.data import Camera
from relaygs.errors import InputError
from relaygs.model import quats_to_rotmats

OPEN_GAP = math.pi / 2  # an azimuth gap wider than this: the cameras do not surround the scene
PATH_CAMERA_ID = -1  # no scene camera has it, so no training camera's colour affine applies
NEAR_PARALLEL = 0.9995  # quaternion dot product above which slerp is replaced by a lerp


def path_cameras(cameras: Sequence[Camera], count: int, centre: Tensor) -> list[Camera]:
    """`count` cameras evenly spaced (by keyframe) along the path through `cameras` around
    `centre` [3]; a loop does not repeat its first camera at the end, so its video repeats
    seamlessly."""
    if count < 1:
        raise InputError(f"camera path: expected at least 1 view, got {count}")
    if not cameras:
        raise InputError("camera path: no cameras to go through")
    keys = path_keyframes(cameras, centre)
    segments = len(keys) - 1
    closed = segments > 0 and keys[0] is keys[-1]
    spacing = segments / (count if closed else max(count - 1, 1))
    path = []
    for view in range(count):
        position = view * spacing
        index = min(int(position), max(segments - 1, 0))
        end = keys[min(index + 1, segments)]
        path.append(_between(keys[index], end, position - index, cameras[0]))
    return path


def path_keyframes(cameras: Sequence[Camera], centre: Tensor) -> list[Camera]:
    """`cameras` in path order: by azimuth around `centre`, starting after the widest gap;
    a loop (no gap wider than OPEN_GAP) ends with its first camera again."""
    c2ws = [camera.c2w.to(torch.float64) for camera in cameras]
    downs = torch.stack([c2w[:3, 1] for c2w in c2ws])  # OpenCV: a camera's y axis points down
    up = _unit(-downs.sum(dim=0), fallback=-downs[0])
    offsets = torch.stack([c2w[:3, 3] for c2w in c2ws]) - centre.to(torch.float64)
    flat = offsets - (offsets @ up)[:, None] * up  # in the plane at right angles to `up`
    e1 = _unit(flat[int(flat.norm(dim=1).argmax())], fallback=_perpendicular(up))
    e2 = torch.linalg.cross(up, e1)
    angles = torch.atan2(flat @ e2, flat @ e1).remainder(2 * math.pi)
    order = sorted(range(len(cameras)), key=lambda index: float(angles[index]))
    sorted_angles = [float(angles[index]) for index in order]
    gaps = [b - a for a, b in pairwise(sorted_angles)]
    gaps.append(sorted_angles[0] + 2 * math.pi - sorted_angles[-1])
    widest = max(range(len(gaps)), key=gaps.__getitem__)
    start = (widest + 1) % len(order)
    keys = [cameras[order[(start + step) % len(order)]] for step in range(len(order))]
    if len(keys) > 1 and gaps[widest] <= OPEN_GAP:
        keys.append(keys[0])
    return keys


def rotmat_to_quat(rotation: Tensor) -> Tensor:
    """The unit wxyz quaternion [4] of a rotation matrix [3, 3], taken from its largest
    diagonal term (Shepperd's method), so no division comes near zero."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    largest = int(torch.stack([trace, m[0, 0], m[1, 1], m[2, 2]]).argmax())
    if largest == 0:
        s = 2.0 * torch.sqrt(1.0 + trace)  # 4w, at least 2: trace >= 0 here
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif largest == 1:
        s = 2.0 * torch.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])  # 4x, at least 2·sqrt(2/3)
        q = [(m[2, 1] - m[1, 2]) / s, s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif largest == 2:
        s = 2.0 * torch.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])  # 4y
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * torch.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])  # 4z
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4]
    quat = torch.stack(q)
    return quat / quat.norm()


def slerp(q0: Tensor, q1: Tensor, t: float) -> Tensor:
    """The unit quaternion a fraction `t` of the shorter arc from `q0` to `q1`."""
    dot = float((q0 * q1).sum())
    if dot < 0.0:  # q and -q are one rotation: take the shorter way round
        q1, dot = -q1, -dot
    if dot > NEAR_PARALLEL:  # sin θ below 0.032: the lerp is as exact and divides by nothing
        blend = q0 + t * (q1 - q0)
        return blend / blend.norm()
    theta = math.acos(dot)
    return (math.sin((1 - t) * theta) * q0 + math.sin(t * theta) * q1) / math.sin(theta)


def _between(start: Camera, end: Camera, t: float, reference: Camera) -> Camera:
    """The pose a fraction `t` from `start` to `end`, with `reference`'s intrinsics and size."""
    first, second = start.w2c.to(torch.float64), end.w2c.to(torch.float64)
    quat = slerp(rotmat_to_quat(first[:3, :3]), rotmat_to_quat(second[:3, :3]), t)
    rotation = quats_to_rotmats(quat)
    centre = (1 - t) * start.center.to(torch.float64) + t * end.center.to(torch.float64)
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = rotation
    w2c[:3, 3] = -rotation @ centre
    return Camera(
        PATH_CAMERA_ID,
        reference.K.clone(),
        w2c.to(reference.w2c.dtype),
        reference.width,
        reference.height,
        reference.near,
    )


def _unit(vector: Tensor, fallback: Tensor) -> Tensor:
    """`vector` scaled to length 1, or `fallback` (scaled) when `vector` is about zero."""
    length = float(vector.norm())
    if length > 1e-9:
        return vector / length
    return fallback / fallback.norm()


def _perpendicular(axis: Tensor) -> Tensor:
    """A unit vector at right angles to the unit `axis`."""
    helper = torch.zeros_like(axis)
    helper[int(axis.abs().argmin())] = 1.0
    return _unit(torch.linalg.cross(axis, helper), fallback=helper)
