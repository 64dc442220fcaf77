"""Nearest neighbours of small 3D point sets (the frame hulls' distance terms), through the
native CPU kernel where the splatting backend takes it, else torch's cdist."""

from __future__ import annotations

import torch
from torch import Tensor

from relaygs.splat import native_kernels_in_use
from relaygs.splat.native.build import load


def nearest_indices(queries: Tensor, points: Tensor) -> Tensor:
    """For each of `queries` [Q, 3] the index (int64 [Q]) of its nearest of `points` [P, 3]
    (P ≥ 1); no gradient. The native kernel scans the points per query without the [Q, P]
    distance matrix that cdist writes (12–20× faster on a CPU at the hulls' sizes)."""
    if native_kernels_in_use(queries):
        return load().nearest_points(queries.detach().contiguous(), points.detach().contiguous())
    return nearest_indices_torch(queries, points)


def nearest_indices_torch(queries: Tensor, points: Tensor) -> Tensor:
    """`nearest_indices` by torch's cdist and argmin (any device; the kernel's reference)."""
    with torch.no_grad():
        return torch.cdist(queries, points).argmin(dim=1)
