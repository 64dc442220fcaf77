"""Camera paths: the orbit a scene's cameras place around its centre, a loop or an arc."""

import math
from itertools import pairwise

import numpy as np
import pytest
import torch

from refusals import refused
from relaygs.camera_path import PATH_CAMERA_ID, path_cameras
from relaygs.data import Camera
from relaygs.data.synthetic.rig import look_at
from relaygs.errors import InputError

TARGET = np.array([0.0, 0.0, 1.0])
CENTRE = torch.tensor(TARGET, dtype=torch.float32)


def _camera(camera_id, azimuth_deg, radius=4.0, height=2.0, width=32):
    angle = math.radians(azimuth_deg)
    eye = np.array([radius * math.cos(angle), radius * math.sin(angle), height])
    K = torch.tensor([[30.0, 0.0, width / 2], [0.0, 30.0, 9.0], [0.0, 0.0, 1.0]])
    w2c = torch.tensor(look_at(eye, TARGET), dtype=torch.float32)
    return Camera(camera_id, K, w2c, width, 18)


def _azimuth(camera):
    centre = camera.center
    return math.degrees(math.atan2(float(centre[1]), float(centre[0]))) % 360


def _same_angles(obtained, expected):
    """Whether the angles (degrees) agree to 1e-3°, 360° apart counting as the same."""
    return len(obtained) == len(expected) and all(
        abs((a - b + 180) % 360 - 180) < 1e-3 for a, b in zip(obtained, expected, strict=True)
    )


def _radius_and_height(camera):
    centre = camera.center.double()
    return float(centre[:2].norm()), float(centre[2])


def _looks_at_the_centre(camera):
    forward = camera.c2w[:3, 2]
    to_centre = CENTRE - camera.center
    return float(forward @ to_centre / to_centre.norm()) > 0.99999


def test_cameras_around_the_centre_make_a_loop_of_upright_views_from_the_first_camera():
    azimuths = [0, 135, 45, 270, 180, 315, 90, 225]  # ids out of order round the ring
    cameras = [_camera(index, azimuth) for index, azimuth in enumerate(azimuths)]
    path = path_cameras(cameras, 16, CENTRE)
    # anticlockwise seen from above; the last view is one step short of the first
    assert _same_angles([_azimuth(view) for view in path], [22.5 * step for step in range(16)])
    for view in path:
        assert _radius_and_height(view) == pytest.approx((4.0, 2.0), abs=1e-5)
        assert _looks_at_the_centre(view)
    for captured, view in zip(cameras, path[::2], strict=False):  # on the orbit: the cameras
        assert torch.allclose(view.w2c, _camera(0, _azimuth(view)).w2c, atol=1e-5)
        assert captured is not view
    # views are upright cameras with the first camera's intrinsics
    cameras = [_camera(3, 0, width=40), _camera(4, 90), _camera(5, 180), _camera(6, 270)]
    for view in path_cameras(cameras, 7, CENTRE):
        assert (view.width, view.height, view.camera_id) == (40, 18, PATH_CAMERA_ID)
        assert torch.equal(view.K, cameras[0].K)
        rotation = view.w2c[:3, :3]
        assert torch.allclose(rotation @ rotation.T, torch.eye(3), atol=1e-5)
        assert float(torch.linalg.det(rotation)) == pytest.approx(1.0, abs=1e-5)
        assert float(view.c2w[2, 1]) < 0  # the image's down axis points down the world
    # a dome of rings gives one orbit at their mean height and radius
    # azimuth order alternates between rings; the path must not bob between them
    cameras = [
        _camera(index, 30 * index, radius=4.0 - index % 3, height=1.5 + index % 3)
        for index in range(12)
    ]
    path = path_cameras(cameras, 24, CENTRE)
    for view in path:
        assert _radius_and_height(view) == pytest.approx((3.0, 2.5), abs=1e-5)
    steps = [_azimuth(b) - _azimuth(a) for a, b in pairwise(path)]
    assert _same_angles(steps, [15.0] * 23)
    # one camera is a still path; bad requests are one line
    cameras = [_camera(0, 10)]
    path = path_cameras(cameras, 3, CENTRE)
    assert all(torch.allclose(view.w2c, cameras[0].w2c, atol=1e-5) for view in path)
    assert len(path_cameras([_camera(0, 0), _camera(1, 90)], 1, CENTRE)) == 1
    with refused(InputError, "camera path", "got 0"):
        path_cameras(cameras, 0, CENTRE)
    with pytest.raises(InputError, match="camera path: no cameras to go round"):
        path_cameras([], 3, CENTRE)
    above = []
    for index in range(3):  # on the vertical through the centre, looking sideways: no orbit
        eye = np.array([0.0, 0.0, 2.0 + index])
        w2c = torch.tensor(look_at(eye, eye + np.array([5.0, 0.0, 0.0])), dtype=torch.float32)
        above.append(Camera(index, cameras[0].K, w2c, 32, 18))
    with refused(InputError, "camera path", "vertical"):
        path_cameras(above, 5, CENTRE)


@pytest.mark.parametrize(
    ("azimuths", "count", "start", "step"),
    [
        ([0, 90, 180, 270], 8, None, 45),  # a right angle apart: a loop, one step short
        ([0, 120, 240], 8, None, 240 / 7),  # wider gaps: the arc over them
        ([60, 0, 30], 5, 0, 15),  # on one side: the arc, from one end
    ],
)
def test_cameras_close_the_loop_only_where_they_surround_the_centre(azimuths, count, start, step):
    cameras = [_camera(index, azimuth) for index, azimuth in enumerate(azimuths)]
    path = path_cameras(cameras, count, CENTRE)
    assert all(_looks_at_the_centre(view) for view in path)
    steps = [_azimuth(b) - _azimuth(a) for a, b in pairwise(path)]  # where it starts may tie
    assert _same_angles(steps, [step] * (count - 1))
    assert start is None or _same_angles([_azimuth(path[0])], [start])
