"""COLMAP text model files (cameras.txt, images.txt, points3D.txt): read and write."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from relaygs.data.colmap.model import CAMERA_MODELS, ColmapCamera, ColmapImage, ColmapModel
from relaygs.data.metafiles import read_text
from relaygs.errors import InputError


def read_text_model(folder: Path) -> ColmapModel:
    """Read cameras.txt, images.txt and points3D.txt from `folder`."""
    xyz, rgb = _read_points(folder / "points3D.txt")
    return ColmapModel(
        cameras=_read_cameras(folder / "cameras.txt"),
        images=_read_images(folder / "images.txt"),
        xyz=xyz,
        rgb=rgb,
    )


def _lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of every line that is not a comment, blank lines included."""
    text = read_text(path)
    return [
        (number, line.strip())
        for number, line in enumerate(text.splitlines(), start=1)
        if not line.lstrip().startswith("#")
    ]


def _bad_line(path: Path, number: int, expected: str) -> InputError:
    return InputError(f"{path} line {number}: expected {expected}")


def _read_cameras(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in _lines(path):
        if not line:
            continue
        fields = line.split()
        expected = "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"
        if len(fields) < 4 or fields[1] not in CAMERA_MODELS:
            raise _bad_line(path, number, expected + " with a known COLMAP model")
        try:
            camera_id, width, height = int(fields[0]), int(fields[2]), int(fields[3])
            params = tuple(float(value) for value in fields[4:])
        except ValueError:
            raise _bad_line(path, number, expected) from None
        if len(params) != CAMERA_MODELS[fields[1]][1]:
            raise _bad_line(path, number, f"{CAMERA_MODELS[fields[1]][1]} {fields[1]} params")
        cameras[camera_id] = ColmapCamera(camera_id, fields[1], width, height, params)
    return cameras


def _read_images(path: Path) -> dict[int, ColmapImage]:
    images = {}
    lines = iter(_lines(path))
    for number, line in lines:
        if not line:
            continue
        fields = line.split(maxsplit=9)
        try:
            image_id, camera_id = int(fields[0]), int(fields[8])
            pose = [float(value) for value in fields[1:8]]
            name = fields[9]
        except (ValueError, IndexError):
            raise _bad_line(path, number, "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME") from None
        _skip_points2d(path, next(lines, None), name)
        images[image_id] = ColmapImage(image_id, tuple(pose[:4]), tuple(pose[4:]), camera_id, name)
    return images


def _skip_points2d(path: Path, line: tuple[int, str] | None, image: str) -> None:
    """Refuse an image line not followed by its 2D points (hand-written models lose images)."""
    if line is not None and len(line[1].split()) % 3:
        expected = f"the POINTS2D line of image {image!r} (X Y POINT3D_ID triples, or empty)"
        raise _bad_line(path, line[0], f"{expected}: each image takes two lines")


def _read_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    xyz, rgb = [], []
    for number, line in _lines(path):
        if not line:
            continue
        fields = line.split()
        try:
            xyz.append([float(value) for value in fields[1:4]])
            rgb.append([int(value) for value in fields[4:7]])
        except ValueError:
            raise _bad_line(path, number, "POINT3D_ID X Y Z R G B ERROR TRACK[]") from None
        if len(fields) < 8 or len(xyz[-1]) != 3 or len(rgb[-1]) != 3:
            raise _bad_line(path, number, "POINT3D_ID X Y Z R G B ERROR TRACK[]")
        if not all(0 <= value <= 255 for value in rgb[-1]):
            raise _bad_line(path, number, f"colour R G B in 0..255, got {rgb[-1]}")
    return np.asarray(xyz, np.float64).reshape(-1, 3), np.asarray(rgb, np.uint8).reshape(-1, 3)


def write_text_model(folder: Path, model: ColmapModel) -> None:
    """Write `model` as cameras.txt, images.txt and points3D.txt (no 2D observations)."""
    folder.mkdir(parents=True, exist_ok=True)
    cameras = ["# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"]
    for camera in model.cameras.values():
        params = " ".join(repr(float(value)) for value in camera.params)
        cameras.append(f"{camera.camera_id} {camera.model} {camera.width} {camera.height} {params}")
    (folder / "cameras.txt").write_text("\n".join(cameras) + "\n", encoding="utf-8")
    images = [
        "# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
        "# POINTS2D[] as (X, Y, POINT3D_ID)",
    ]
    for image in model.images.values():
        pose = " ".join(repr(float(value)) for value in (*image.qvec, *image.tvec))
        images.extend([f"{image.image_id} {pose} {image.camera_id} {image.name}", ""])
    (folder / "images.txt").write_text("\n".join(images) + "\n", encoding="utf-8")
    points = ["# POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    for index, (xyz, rgb) in enumerate(zip(model.xyz, model.rgb, strict=True)):
        coords = " ".join(repr(float(value)) for value in xyz)
        points.append(f"{index + 1} {coords} {int(rgb[0])} {int(rgb[1])} {int(rgb[2])} 0.0")
    (folder / "points3D.txt").write_text("\n".join(points) + "\n", encoding="utf-8")
