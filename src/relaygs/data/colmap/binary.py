"""COLMAP binary model files (cameras.bin, images.bin, points3D.bin): read and write."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from relaygs.data.colmap.model import (
    CAMERA_MODELS,
    MODEL_NAMES,
    ColmapCamera,
    ColmapImage,
    ColmapModel,
)
from relaygs.errors import InputError

# The smallest record of each file, to bound a record count by the bytes that follow it.
_LEAST_CAMERA = "iiQQ3d"  # SIMPLE_PINHOLE, the model with the fewest parameters
_LEAST_IMAGE = "I7dIxQ"  # an empty name (just its NUL) and no 2D points
_LEAST_POINT = "Q3d3BdQ"  # an empty track


class _Reader:
    """Sequential little-endian reader over a file's bytes, failing with the file's name."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def unpack(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise InputError(f"{self.path}: file is truncated at byte {self.pos}")
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def count(self, least: str, what: str) -> int:
        """A record count, refused when the bytes left cannot hold that many `least` records, so a
        damaged count fails before anything is allocated."""
        count = self.unpack("Q")[0]
        left, size = len(self.data) - self.pos, struct.calcsize("<" + least)
        if count * size > left:
            raise InputError(
                f"{self.path}: declares {count} {what} but the {left} bytes that follow hold at "
                f"most {left // size}; the file is damaged"
            )
        return count

    def string(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise InputError(f"{self.path}: unterminated image name at byte {self.pos}")
        text = self.data[self.pos : end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return text


def read_binary_model(folder: Path) -> ColmapModel:
    """Read cameras.bin, images.bin and points3D.bin from `folder`."""
    return ColmapModel(
        cameras=_read_cameras(folder / "cameras.bin"),
        images=_read_images(folder / "images.bin"),
        **_read_points(folder / "points3D.bin"),
    )


def _read_cameras(path: Path) -> dict[int, ColmapCamera]:
    reader = _Reader(path)
    cameras = {}
    for _ in range(reader.count(_LEAST_CAMERA, "cameras")):
        camera_id, model_id, width, height = reader.unpack("iiQQ")
        if model_id not in MODEL_NAMES:
            raise InputError(f"{path}: camera {camera_id} has unknown model id {model_id}")
        model = MODEL_NAMES[model_id]
        params = reader.unpack("d" * CAMERA_MODELS[model][1])
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def _read_images(path: Path) -> dict[int, ColmapImage]:
    reader = _Reader(path)
    images = {}
    for _ in range(reader.count(_LEAST_IMAGE, "images")):
        image_id, *pose, camera_id = reader.unpack("I7dI")
        name = reader.string()
        reader.unpack(f"{reader.unpack('Q')[0] * struct.calcsize('<ddq')}x")  # 2D points
        images[image_id] = ColmapImage(image_id, tuple(pose[:4]), tuple(pose[4:]), camera_id, name)
    return images


def _read_points(path: Path) -> dict[str, np.ndarray]:
    reader = _Reader(path)
    count = reader.count(_LEAST_POINT, "points")
    xyz = np.zeros((count, 3))
    rgb = np.zeros((count, 3), dtype=np.uint8)
    for index in range(count):
        values = reader.unpack("Q3d3Bd")
        xyz[index] = values[1:4]
        rgb[index] = values[4:7]
        reader.unpack(f"{reader.unpack('Q')[0] * struct.calcsize('<ii')}x")  # its track
    return {"xyz": xyz, "rgb": rgb}


def write_binary_model(folder: Path, model: ColmapModel) -> None:
    """Write `model` as cameras.bin, images.bin and points3D.bin (no 2D observations)."""
    folder.mkdir(parents=True, exist_ok=True)
    cameras = [struct.pack("<Q", len(model.cameras))]
    for camera in model.cameras.values():
        model_id, num_params = CAMERA_MODELS[camera.model]
        head = struct.pack("<iiQQ", camera.camera_id, model_id, camera.width, camera.height)
        cameras.append(head + struct.pack(f"<{num_params}d", *camera.params))
    (folder / "cameras.bin").write_bytes(b"".join(cameras))
    images = [struct.pack("<Q", len(model.images))]
    for image in model.images.values():
        pose = struct.pack("<I7dI", image.image_id, *image.qvec, *image.tvec, image.camera_id)
        images.append(pose + image.name.encode("utf-8") + b"\x00" + struct.pack("<Q", 0))
    (folder / "images.bin").write_bytes(b"".join(images))
    points = [struct.pack("<Q", len(model.xyz))]
    for index, (xyz, rgb) in enumerate(zip(model.xyz, model.rgb, strict=True)):
        points.append(struct.pack("<Q3d3BdQ", index + 1, *xyz, *rgb, 0.0, 0))
    (folder / "points3D.bin").write_bytes(b"".join(points))
