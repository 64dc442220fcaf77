"""Write tests/data/pycolmap: a sparse model written by COLMAP's own code (pycolmap), binary and
text, and expected.json with what pycolmap reads in it, so the tests check relaygs's COLMAP
reader against an independent writer of the current format (a two-camera rig, frames, tracks
included).

pycolmap is not a relaygs dependency; run this in a virtualenv of its own:
    python3 -m venv /tmp/pycolmap && /tmp/pycolmap/bin/pip install pycolmap==4.2.1 numpy
    /tmp/pycolmap/bin/python tools/make_pycolmap_fixture.py
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pycolmap

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "pycolmap"
CAMERAS = (  # (camera id, model, params): every model relaygs reads without undistortion
    (1, "PINHOLE", [50.0, 51.5, 32.25, 17.75]),
    (4, "SIMPLE_PINHOLE", [48.0, 31.5, 18.0]),
    (9, "OPENCV", [47.0, 49.0, 31.0, 17.0, 0.0, 0.0, 0.0, 0.0]),
)
WIDTH, HEIGHT = 64, 36
POINTS = 6


def build() -> pycolmap.Reconstruction:
    """Three posed cameras, one image each at frame 0: cam00 and cam01 on one rig (cam01's pose
    is its sensor_from_rig composed with the frame's rig_from_world), cam02 alone; points with
    two-view tracks."""
    rng = np.random.default_rng(7)
    reconstruction = pycolmap.Reconstruction()
    cameras = [
        pycolmap.Camera(model=model, width=WIDTH, height=HEIGHT, params=params, camera_id=camera_id)
        for camera_id, model, params in CAMERAS
    ]
    images = [
        pycolmap.Image(
            name=f"cam{index:02d}/frame_00000.png",
            camera_id=camera.camera_id,
            image_id=20 + index,
            points2D=[pycolmap.Point2D(_keypoint(rng)) for _ in range(POINTS)],
        )
        for index, camera in enumerate(cameras)
    ]
    rig = pycolmap.Rig(rig_id=1)
    rig.add_ref_sensor(cameras[0].sensor_id)
    rig.add_sensor(cameras[1].sensor_id, _pose(rng))
    for camera in cameras[:2]:
        reconstruction.add_camera(camera)
    reconstruction.add_rig(rig)
    frame = pycolmap.Frame(frame_id=1, rig_id=rig.rig_id)
    frame.rig_from_world = _pose(rng)
    for image in images[:2]:
        image.frame_id = frame.frame_id
        frame.add_data_id(image.data_id)
    reconstruction.add_frame(frame)
    for image in images[:2]:
        reconstruction.add_image(image)
    reconstruction.register_frame(frame.frame_id)
    reconstruction.add_camera_with_trivial_rig(cameras[2])
    reconstruction.add_image_with_trivial_frame(images[2], _pose(rng))
    for point in range(POINTS):
        track = pycolmap.Track()
        track.add_element(20 + point % 3, point)
        track.add_element(20 + (point + 1) % 3, point)
        color = np.array([40 * point, 255 - point, 7], dtype=np.uint8)
        reconstruction.add_point3D(rng.normal(size=3), track, color)
    return reconstruction


def _pose(rng: np.random.Generator) -> pycolmap.Rigid3d:
    """A random rigid transform."""
    wxyz = rng.normal(size=4)
    wxyz /= np.linalg.norm(wxyz)
    rotation = pycolmap.Rotation3d(np.array([*wxyz[1:], wxyz[0]]))  # Eigen order: x y z w
    return pycolmap.Rigid3d(rotation, rng.normal(size=3))


def _keypoint(rng: np.random.Generator) -> np.ndarray:
    """A random pixel position inside the image."""
    return rng.uniform((0, 0), (WIDTH, HEIGHT))


def expected(reconstruction: pycolmap.Reconstruction) -> dict:
    """What pycolmap reads: per image its pose (quaternion w first, rotation matrix,
    translation) and intrinsics matrix; per point its position and colour."""
    images = {}
    for image in reconstruction.images.values():
        pose = image.cam_from_world()
        camera = reconstruction.cameras[image.camera_id]
        x, y, z, w = pose.rotation.quat
        images[image.name] = {
            "image_id": image.image_id,
            "camera_id": image.camera_id,
            "model": camera.model.name,
            "params": list(camera.params),
            "qvec": [w, x, y, z],
            "rotation": pose.rotation.matrix().tolist(),
            "tvec": list(pose.translation),
            "K": camera.calibration_matrix().tolist(),
        }
    points = sorted(
        (list(point.xyz), [int(c) for c in point.color])
        for point in reconstruction.points3D.values()
    )
    return {
        "pycolmap": pycolmap.__version__,
        "size": [WIDTH, HEIGHT],
        "images": images,
        "xyz": [xyz for xyz, _ in points],
        "rgb": [rgb for _, rgb in points],
    }


def main() -> None:
    """Write the binary and text models and expected.json (read back from the binary one)."""
    shutil.rmtree(OUT, ignore_errors=True)
    reconstruction = build()
    for kind, write in (("bin", reconstruction.write_binary), ("txt", reconstruction.write_text)):
        (OUT / kind).mkdir(parents=True)
        write(str(OUT / kind))
    written = pycolmap.Reconstruction(str(OUT / "bin"))
    (OUT / "expected.json").write_text(json.dumps(expected(written), indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
