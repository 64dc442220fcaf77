"""Pinhole camera model shared by every loader, the generator and the renderer."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from relaygs.errors import InputError

POSE_TOLERANCE = 1e-3
"""How far a loaded rotation may be from orthonormal (largest entry of |R Rᵀ - I|)."""

NEAR_PLANE = 0.01
"""Near-plane distance of the splatting core (gsplat's default), used as is for scenes of extent
>= 1 and scaled with the extent below it (`near_plane_for`)."""


def near_plane_for(extent: float) -> float:
    """A scene's near plane: NEAR_PLANE × min(1, extent), so a capture in small units (cameras
    millimetres from the subject) is not culled whole while every scene of extent >= 1 keeps
    gsplat's 0.01."""
    return NEAR_PLANE * min(1.0, extent)


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera: intrinsics K, world→camera pose (OpenCV axes) and image size.

    Pixel j covers [j, j + 1) in image coordinates, so its centre is at j + 0.5 (the
    convention of COLMAP and the 3DGS rasteriser). `near`: depth below which Gaussians are
    culled (the loaders set it from the scene's extent, `near_plane_for`).
    """

    camera_id: int
    K: torch.Tensor
    w2c: torch.Tensor
    width: int
    height: int
    near: float = NEAR_PLANE

    def scaled(self, factor: float) -> Camera:
        """The same camera seen at 1/`factor` resolution (factor 2 gives half-size images).

        Sizes round to the nearest pixel (at least 1) and K scales by the exact per-axis ratio,
        so projected pixel-edge coordinates stay consistent with the resized image.
        """
        if not factor > 0:
            raise ValueError(f"camera scale factor must be > 0, got {factor}")
        width = max(1, round(self.width / factor))
        height = max(1, round(self.height / factor))
        if width == self.width and height == self.height:
            return self
        scale = torch.tensor(
            [[width / self.width], [height / self.height], [1.0]], dtype=torch.float32
        )
        return Camera(self.camera_id, self.K * scale, self.w2c.clone(), width, height, self.near)

    @property
    def center(self) -> torch.Tensor:
        """Camera centre in world coordinates [3]."""
        rotation = self.w2c[:3, :3]
        return -(rotation.T @ self.w2c[:3, 3])

    @property
    def c2w(self) -> torch.Tensor:
        """Camera→world transform [4,4] (the rigid inverse of w2c)."""
        c2w = torch.eye(4, dtype=self.w2c.dtype)
        c2w[:3, :3] = self.w2c[:3, :3].T
        c2w[:3, 3] = self.center
        return c2w


def check_intrinsics(K: np.ndarray, where: str) -> None:
    """Raise InputError naming `where` unless every K [..., 3, 3] is a pinhole matrix with
    finite entries and positive focal lengths (the projection divides by them)."""
    if not (bool(np.isfinite(K).all()) and _is_pinhole(K)):
        raise InputError(
            f"{where} must hold intrinsics [[fx,0,cx],[0,fy,cy],[0,0,1]] with finite entries "
            "and fx, fy > 0"
        )


def _is_pinhole(K: np.ndarray) -> bool:
    return bool(
        np.allclose(K[..., 2, :], [0.0, 0.0, 1.0])
        and (K[..., 0, 0] > 0).all()
        and (K[..., 1, 1] > 0).all()
    )


def check_rigid(w2c: np.ndarray, where: str) -> None:
    """Raise InputError naming `where` unless every w2c [..., 4, 4] is a finite rigid transform."""
    if not (bool(np.isfinite(w2c).all()) and _is_rigid(w2c)):
        raise InputError(
            f"{where} must hold rigid world→camera transforms "
            "(finite, rotation with det +1, last row 0 0 0 1)"
        )


def _is_rigid(w2c: np.ndarray) -> bool:
    rotation = w2c[..., :3, :3]
    gram = rotation @ np.swapaxes(rotation, -1, -2)
    return bool(
        np.abs(gram - np.eye(3)).max() < POSE_TOLERANCE
        and (np.linalg.det(rotation) > 0).all()
        and np.allclose(w2c[..., 3, :], [0.0, 0.0, 0.0, 1.0])
    )
