"""COLMAP sparse-model records (cameras, images, points) and quaternion conversions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CAMERA_MODELS: dict[str, tuple[int, int]] = {
    "SIMPLE_PINHOLE": (0, 3),
    "PINHOLE": (1, 4),
    "SIMPLE_RADIAL": (2, 4),
    "RADIAL": (3, 5),
    "OPENCV": (4, 8),
    "OPENCV_FISHEYE": (5, 8),
    "FULL_OPENCV": (6, 12),
    "FOV": (7, 5),
    "SIMPLE_RADIAL_FISHEYE": (8, 4),
    "RADIAL_FISHEYE": (9, 5),
    "THIN_PRISM_FISHEYE": (10, 12),
}
"""COLMAP camera model name → (model id, number of parameters)."""
MODEL_NAMES: dict[int, str] = {model_id: name for name, (model_id, _) in CAMERA_MODELS.items()}


@dataclass(frozen=True)
class ColmapCamera:
    """An intrinsics record: model name, image size and the model's parameter list."""

    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class ColmapImage:
    """A registered image: world→camera rotation (quaternion w, x, y, z) and translation."""

    image_id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int
    name: str

    def w2c(self) -> np.ndarray:
        """World→camera transform [4,4] float64."""
        matrix = np.eye(4)
        matrix[:3, :3] = qvec_to_rotation(np.asarray(self.qvec, dtype=np.float64))
        matrix[:3, 3] = self.tvec
        return matrix


@dataclass(frozen=True)
class ColmapModel:
    """A sparse model: cameras and images by id, points as xyz [N,3] float64, rgb [N,3] uint8."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    xyz: np.ndarray
    rgb: np.ndarray


def qvec_to_rotation(qvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z); the quaternion is normalised first, so it
    must be finite and non-zero (ValueError otherwise: loaders check poses before this)."""
    norm = float(np.linalg.norm(qvec))
    if not (np.isfinite(norm) and norm > 0):
        raise ValueError(f"quaternion {list(qvec)} has norm {norm}; expected a finite non-zero one")
    w, x, y, z = qvec / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotation_to_qvec(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix: the top eigenvector of
    Bar-Itzhack's symmetric 4×4 matrix, which also takes a nearly orthonormal one."""
    r = np.asarray(rotation, dtype=np.float64)
    (xx, xy, xz), (yx, yy, yz), (zx, zy, zz) = r
    symmetric = [
        [xx + yy + zz, zy - yz, xz - zx, yx - xy],
        [zy - yz, xx - yy - zz, xy + yx, xz + zx],
        [xz - zx, xy + yx, yy - xx - zz, yz + zy],
        [yx - xy, xz + zx, yz + zy, zz - xx - yy],
    ]
    values, vectors = np.linalg.eigh(np.array(symmetric) / 3.0)
    quaternion = vectors[:, np.argmax(values)]
    return quaternion if quaternion[0] >= 0 else -quaternion
