"""Camera paths through a scene's cameras: order, loop or open ends, and interpolated poses."""

import math
from itertools import pairwise

import numpy as np
import pytest
import torch

from relaygs.camera_path import (
    PATH_CAMERA_ID,
    path_cameras,
    path_keyframes,
    rotmat_to_quat,
    slerp,
)
from relaygs.data import Camera
from relaygs.data.synthetic.rig import look_at
from relaygs.errors import InputError
from relaygs.model import quats_to_rotmats

TARGET = np.array([0.0, 0.0, 1.0])
ORIGIN = torch.tensor(TARGET, dtype=torch.float32)


def _camera(camera_id, azimuth_deg, radius=4.0, height=2.0, width=32):
    angle = math.radians(azimuth_deg)
    eye = np.array([radius * math.cos(angle), radius * math.sin(angle), height])
    K = torch.tensor([[30.0, 0.0, width / 2], [0.0, 30.0, 9.0], [0.0, 0.0, 1.0]])
    w2c = torch.tensor(look_at(eye, TARGET), dtype=torch.float32)
    return Camera(camera_id, K, w2c, width, 18)


def _azimuth(camera):
    centre = camera.center
    return math.degrees(math.atan2(float(centre[1]), float(centre[0]))) % 360


def _same_pose(a, b):
    return torch.allclose(a.w2c, b.w2c, atol=1e-5)


def _random_rotations(count):
    generator = torch.Generator().manual_seed(0)
    quats = torch.randn(count, 4, generator=generator, dtype=torch.float64)
    return quats_to_rotmats(quats / quats.norm(dim=1, keepdim=True))


def test_a_rotation_comes_back_from_its_quaternion_including_half_turns():
    half_turns = torch.stack(
        [torch.diag(torch.tensor(d, dtype=torch.float64)) for d in ([1, -1, -1], [-1, 1, -1])]
    )
    for rotation in torch.cat([_random_rotations(50), half_turns]):
        quat = rotmat_to_quat(rotation)
        assert torch.isfinite(quat).all() and math.isclose(float(quat.norm()), 1.0)
        assert torch.allclose(quats_to_rotmats(quat), rotation, atol=1e-12)


def test_slerp_keeps_its_ends_halves_the_angle_and_takes_the_shorter_arc():
    q0 = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    turn = math.radians(120)  # about z
    q1 = torch.tensor([math.cos(turn / 2), 0.0, 0.0, math.sin(turn / 2)], dtype=torch.float64)
    assert torch.allclose(slerp(q0, q1, 0.0), q0) and torch.allclose(slerp(q0, q1, 1.0), q1)
    half = torch.tensor([math.cos(turn / 4), 0.0, 0.0, math.sin(turn / 4)], dtype=torch.float64)
    assert torch.allclose(slerp(q0, q1, 0.5), half)
    assert torch.allclose(slerp(q0, -q1, 0.5), half)  # -q1 is the same rotation
    nearly = torch.tensor([1.0, 1e-4, 0.0, 0.0], dtype=torch.float64)
    nearly = nearly / nearly.norm()
    assert math.isclose(float(slerp(q0, nearly, 0.3).norm()), 1.0)


def test_cameras_around_the_centre_make_a_loop_in_azimuth_order():
    azimuths = [0, 135, 45, 270, 180, 315, 90, 225]  # ids out of order round the ring
    cameras = [_camera(index, azimuth) for index, azimuth in enumerate(azimuths)]
    keys = path_keyframes(cameras, ORIGIN)
    assert len(keys) == 9 and keys[0] is keys[-1]  # a loop
    steps = [(_azimuth(b) - _azimuth(a)) % 360 for a, b in pairwise(keys)]
    assert steps == pytest.approx([45] * 8, abs=1e-3)  # anticlockwise seen from above
    path = path_cameras(cameras, 16, ORIGIN)
    assert len(path) == 16
    for index, key in enumerate(keys[:-1]):  # every other view is a captured camera
        assert _same_pose(path[2 * index], key)
    between = path[1]  # halfway along the arc: azimuth halfway, still looking at the centre
    assert (_azimuth(between) - _azimuth(keys[0])) % 360 == pytest.approx(22.5, abs=1e-3)
    forward = between.c2w[:3, 2]
    to_centre = ORIGIN - between.center
    assert float(forward @ to_centre / to_centre.norm()) > 0.999


def test_cameras_on_one_side_make_an_open_path_from_end_to_end():
    cameras = [_camera(0, 60), _camera(1, 0), _camera(2, 30)]
    keys = path_keyframes(cameras, ORIGIN)
    assert [key.camera_id for key in keys] == [1, 2, 0]  # from 0° to 60°, no wrap-around
    path = path_cameras(cameras, 5, ORIGIN)
    assert _same_pose(path[0], keys[0]) and _same_pose(path[-1], keys[-1])
    assert _same_pose(path[2], cameras[2])  # the middle camera halfway along
    assert [_azimuth(camera) for camera in path] == pytest.approx([0, 15, 30, 45, 60], abs=1e-3)


def test_path_cameras_take_the_first_cameras_intrinsics_and_match_no_scene_camera():
    cameras = [_camera(3, 0, width=40), _camera(4, 90), _camera(5, 180), _camera(6, 270)]
    path = path_cameras(cameras, 7, ORIGIN)
    for camera in path:
        assert (camera.width, camera.height, camera.camera_id) == (40, 18, PATH_CAMERA_ID)
        assert torch.equal(camera.K, cameras[0].K)
        rotation = camera.w2c[:3, :3]
        assert torch.allclose(rotation @ rotation.T, torch.eye(3), atol=1e-5)


def test_one_camera_is_a_still_path_and_bad_requests_are_one_line():
    (camera,) = cameras = [_camera(0, 10)]
    assert all(_same_pose(view, camera) for view in path_cameras(cameras, 3, ORIGIN))
    assert len(path_cameras([_camera(0, 0), _camera(1, 90)], 1, ORIGIN)) == 1
    with pytest.raises(InputError, match="camera path: expected at least 1 view, got 0"):
        path_cameras(cameras, 0, ORIGIN)
    with pytest.raises(InputError, match="camera path: no cameras to go through"):
        path_cameras([], 3, ORIGIN)


def test_cameras_right_above_the_centre_still_make_a_path():
    # no azimuth to sort by (every centre on the up axis through the centre): a path all the same
    eyes = [np.array([0.0, 0.0, 2.0 + index]) for index in range(3)]
    w2cs = [look_at(eye, eye + np.array([5.0, 0.0, 0.0])) for eye in eyes]
    K = torch.tensor([[30.0, 0.0, 16.0], [0.0, 30.0, 9.0], [0.0, 0.0, 1.0]])
    cameras = [
        Camera(index, K, torch.tensor(w2c, dtype=torch.float32), 32, 18)
        for index, w2c in enumerate(w2cs)
    ]
    path = path_cameras(cameras, 5, ORIGIN)
    assert all(torch.isfinite(camera.w2c).all() for camera in path)
    heights = sorted(float(camera.center[2]) for camera in path)
    assert heights == pytest.approx([2.0, 2.5, 3.0, 3.5, 4.0])
