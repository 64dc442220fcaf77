"""Initial point cloud of a scene: validation and voxel downsampling to a size budget."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from relaygs.data.finite import FINITE, finite_in_float32
from relaygs.errors import InputError

_SEARCH_STEPS = 16
_CELL_BITS = 20


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points that seed the Gaussians: xyz [N,3] float32, rgb [N,3] in [0,1], is_fg [N] bool."""

    xyz: torch.Tensor
    rgb: torch.Tensor
    is_fg: torch.Tensor

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def point_cloud_from_arrays(
    xyz: np.ndarray, rgb: np.ndarray, is_fg: np.ndarray, *, source: str, max_points: int
) -> PointCloud:
    """Check a raw cloud (non-empty, finite, rgb in [0,1]) and voxel-downsample it to max_points."""
    xyz = np.asarray(xyz, dtype=np.float64)
    rgb = np.asarray(rgb, dtype=np.float64)
    is_fg = np.asarray(is_fg, dtype=bool)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.shape[0] == 0:
        raise InputError(f"{source}: expected a non-empty point cloud, got xyz shape {xyz.shape}")
    if not (finite_in_float32(xyz).all() and finite_in_float32(rgb).all()):
        raise InputError(f"{source}: point cloud holds values not finite in float32 ({FINITE})")
    if rgb.min() < 0.0 or rgb.max() > 1.0:
        raise InputError(
            f"{source}: point colours must lie in [0, 1], got range "
            f"[{rgb.min():.3g}, {rgb.max():.3g}]"
        )
    xyz, rgb, is_fg = voxel_downsample(xyz, rgb, is_fg, max_points)
    return PointCloud(
        xyz=torch.from_numpy(xyz.astype(np.float32)),
        rgb=torch.from_numpy(rgb.astype(np.float32)),
        is_fg=torch.from_numpy(is_fg),
    )


def voxel_downsample(
    xyz: np.ndarray, rgb: np.ndarray, is_fg: np.ndarray, max_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Average points per voxel (fg and bg apart), the voxel size bisected in log space to the
    finest giving ≤ max_points (deterministic); a cloud within budget is returned as is."""
    if len(xyz) <= max_points:
        return xyz, rgb, is_fg
    span = float(np.ptp(xyz, axis=0).max())
    low, high = span / 2**_CELL_BITS + 1e-12, span * 2.0 + 1e-12
    best = _voxel_groups(xyz, is_fg, high)
    for _ in range(_SEARCH_STEPS):
        mid = float(np.sqrt(low * high))
        groups = _voxel_groups(xyz, is_fg, mid)
        if groups[1] <= max_points:
            high, best = mid, groups
        else:
            low = mid
    inverse, count = best
    sizes = np.bincount(inverse, minlength=count).astype(np.float64)[:, None]
    mean_xyz = _group_sum(inverse, xyz, count) / sizes
    mean_rgb = _group_sum(inverse, rgb, count) / sizes
    group_fg = np.zeros(count, dtype=bool)
    group_fg[inverse] = is_fg
    return mean_xyz, mean_rgb, group_fg


def _voxel_groups(xyz: np.ndarray, is_fg: np.ndarray, size: float) -> tuple[np.ndarray, int]:
    cells = np.floor((xyz - xyz.min(axis=0)) / size).astype(np.int64)
    cells = np.minimum(cells, 2**_CELL_BITS - 1)
    keys = (cells[:, 0] << (2 * _CELL_BITS + 1)) | (cells[:, 1] << (_CELL_BITS + 1))
    keys |= (cells[:, 2] << 1) | is_fg.astype(np.int64)
    _, inverse = np.unique(keys, return_inverse=True)
    return inverse, int(inverse.max()) + 1


def _group_sum(inverse: np.ndarray, values: np.ndarray, count: int) -> np.ndarray:
    return np.stack(
        [np.bincount(inverse, weights=values[:, k], minlength=count) for k in range(3)], axis=1
    )
