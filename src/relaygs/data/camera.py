"""Pinhole camera model shared by every loader, the generator and the renderer."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from relaygs.data.finite import finite_in_float32
from relaygs.errors import InputError
from relaygs.splat.projection import MAX_FOCAL

POSE_TOLERANCE = 1e-3  # how far a loaded rotation may be from orthonormal: max |R Rᵀ - I|
NEAR_PLANE = 0.01  # gsplat's default near plane, for scenes of extent >= 1 (`near_plane_for`)


def near_plane_for(extent: float) -> float:
    """NEAR_PLANE × min(1, extent): a capture in small units is not culled whole."""
    return NEAR_PLANE * min(1.0, extent)


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera: K, world→camera pose (OpenCV axes), image size; pixel j covers [j, j+1)
    as in COLMAP and 3DGS; Gaussians nearer than `near` are culled."""

    camera_id: int
    K: torch.Tensor
    w2c: torch.Tensor
    width: int
    height: int
    near: float = NEAR_PLANE

    def scaled(self, factor: float) -> Camera:
        """This camera at 1/`factor` resolution: sizes round (at least 1) and K scales by the exact
        per-axis ratio, so pixel edges stay consistent with the resized image."""
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

    def project(self, points: torch.Tensor, min_depth: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Pixels [N,2] of world points [N,3], and whether each lies deeper than `min_depth` and
        inside the image (a point behind gets depth-1 coordinates: finite, flagged outside)."""
        homogeneous = torch.cat([points, points.new_ones(points.shape[0], 1)], dim=1)
        cam = homogeneous @ self.w2c.to(torch.float32).T
        depth = cam[:, 2]
        in_front = depth > min_depth
        safe_depth = torch.where(in_front, depth, torch.ones_like(depth))
        pixels = ((cam[:, :3] / safe_depth[:, None]) @ self.K.to(torch.float32).T)[:, :2]
        column, row = pixels[:, 0].floor(), pixels[:, 1].floor()
        inside = in_front & (column >= 0) & (column < self.width) & (row >= 0) & (row < self.height)
        return pixels, inside

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


INTRINSICS_FORM = (
    "intrinsics [[fx,0,cx],[0,fy,cy],[0,0,1]] with finite entries and "
    f"0 < fx, fy <= {MAX_FOCAL:.0e}"
)
RIGID_FORM = "a rigid world→camera transform (finite, rotation with det +1, last row 0 0 0 1)"
_INTRINSIC_NAMES = {(0, 0): "fx", (1, 1): "fy", (0, 2): "cx", (1, 2): "cy"}
MAX_SKEW = 1e-3
"""Skew (K[0][1], K[1][0]) up to this fraction of fx, fy is taken for zero; a larger one,
which the renderer cannot model, is refused."""


def _bracketed(index: tuple[int, ...]) -> str:
    """How a check names a bad matrix of a batch by default: " at [2][1]" ("" for one matrix)."""
    return " at " + "".join(f"[{i}]" for i in index) if index else ""


def check_intrinsics(
    K: np.ndarray,
    where: str,
    at: Callable[[tuple[int, ...]], str] = _bracketed,
    size: tuple[int, int] | None = None,
) -> None:
    """InputError naming `where` and the first bad K [..., 3, 3] (`at` its index) unless each is
    a finite pinhole matrix with fx, fy > 0 and, given `size`, its centre inside the image."""
    found = _first_problem(K, lambda k: _intrinsics_problem(k, size))
    if found is not None:
        inside = f" and the principal point inside the {size[0]}x{size[1]} image" if size else ""
        raise InputError(
            f"{where}{at(found[0])} has {found[1]}; expected {INTRINSICS_FORM}{inside}"
        )


def _first_problem(
    matrices: np.ndarray, describe: Callable[[np.ndarray], str]
) -> tuple[tuple[int, ...], str] | None:
    """(index, problems) of the first matrix of a batch [..., n, n] that `describe` finds any in;
    each distinct matrix is described once (a fixed rig repeats its cameras every frame)."""
    flat = matrices.reshape(-1, *matrices.shape[-2:])
    _, first = np.unique(flat.reshape(len(flat), -1), axis=0, return_index=True)
    for position in sorted(first):
        if problem := describe(flat[position]):
            index = np.unravel_index(position, matrices.shape[:-2])
            return tuple(int(i) for i in index), problem
    return None


def _intrinsics_problem(k: np.ndarray, size: tuple[int, int] | None = None) -> str:
    """The bad values of one K [3, 3]: non-finite, focal, principal point, skew, last row."""
    problems = [
        f"{_INTRINSIC_NAMES.get((i, j), f'K[{i}][{j}]')} = {float(k[i, j])}"
        for i, j in np.ndindex(3, 3)
        if not finite_in_float32(k[i, j])
        or ((i, j) in ((0, 0), (1, 1)) and not 0 < k[i, j] <= MAX_FOCAL)
    ]
    if size is not None and finite_in_float32(k[:2, 2]).all():
        problems += [
            f"{name} = {float(value)} outside 0..{limit}"
            for name, value, limit in (("cx", k[0, 2], size[0]), ("cy", k[1, 2], size[1]))
            if not 0 < value < limit
        ]
    skewed = abs(k[0, 1]) > MAX_SKEW * abs(k[0, 0]) or abs(k[1, 0]) > MAX_SKEW * abs(k[1, 1])
    if finite_in_float32(k[:2, :2]).all() and skewed:
        problems.append(f"skew K[0][1] = {float(k[0, 1])}, K[1][0] = {float(k[1, 0])}")
    if finite_in_float32(k[2]).all() and not np.allclose(k[2], [0.0, 0.0, 1.0]):
        problems.append(f"last row {k[2].tolist()}")
    return ", ".join(problems)


def check_rigid(
    w2c: np.ndarray, where: str, at: Callable[[tuple[int, ...]], str] = _bracketed
) -> None:
    """Raise InputError unless every w2c [..., 4, 4] is a finite rigid transform; the message
    names `where`, the first bad matrix (`at` its leading indices) and what is wrong with it."""
    found = _first_problem(w2c, _rigid_problem)
    if found is not None:
        raise InputError(f"{where}{at(found[0])} has {found[1]}; expected {RIGID_FORM}")


def _rigid_problem(w2c: np.ndarray) -> str:
    """What makes one w2c [4, 4] no rigid transform: non-finite, rotation, last row."""
    if not finite_in_float32(w2c).all():
        return f"entries not finite in float32 {w2c.tolist()}"
    rotation = w2c[:3, :3]
    problems = []
    error = float(np.abs(rotation @ rotation.T - np.eye(3)).max())
    if error >= POSE_TOLERANCE:
        problems.append(f"a rotation that is not orthonormal (|R Rᵀ - I| up to {error:.3g})")
    determinant = float(np.linalg.det(rotation))
    if determinant <= 0:
        problems.append(f"a rotation of det {determinant:.3g}")
    if not np.allclose(w2c[3], [0.0, 0.0, 0.0, 1.0]):
        problems.append(f"last row {w2c[3].tolist()}")
    return ", ".join(problems)
