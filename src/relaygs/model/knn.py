"""Exact nearest-neighbour distances in bounded memory: blocks along a Morton curve, each
searched in its box grown by a bound on its k-th distances (cdist, exact recheck)."""

from __future__ import annotations

import torch
from torch import Tensor

EXTRA_CANDIDATES = 5  # spare neighbours so matrix-form rounding cannot drop a true neighbour
DEFAULT_CHUNK_ELEMENTS = 1 << 24  # ≈ 64 MB of float32 distances per cdist chunk
BLOCK_SIZE = 256  # query points per spatial block
MORTON_BITS = 10  # quantisation bits per axis for the Z-order sort


@torch.no_grad()
def mean_sq_knn_distance(
    points: Tensor, k: int = 3, chunk_elements: int = DEFAULT_CHUNK_ELEMENTS
) -> Tensor:
    """Mean squared distance [N] from each point to its k nearest other points (0 if N == 1)."""
    n = points.shape[0]
    k_used = min(k, n - 1)
    if k_used <= 0:
        return torch.zeros(n, dtype=points.dtype, device=points.device)
    centred = points - points.mean(dim=0)
    order = _morton_order(centred)
    ordered = centred[order]
    ids = torch.arange(n, device=points.device)
    result = torch.empty(n, dtype=points.dtype, device=points.device)
    for start in range(0, n, BLOCK_SIZE):
        stop = min(n, start + BLOCK_SIZE)
        block, block_ids = ordered[start:stop], ids[start:stop]
        lo, hi = max(0, start - BLOCK_SIZE), min(n, stop + BLOCK_SIZE)
        window = _nearest_sq(block, ordered[lo:hi], block_ids, ids[lo:hi], k_used, chunk_elements)
        radius = window[:, -1].max().sqrt() * (1.0 + 1e-4) + 1e-12
        low, high = block.amin(dim=0) - radius, block.amax(dim=0) + radius
        pool_ids = ((ordered >= low) & (ordered <= high)).all(dim=1).nonzero().squeeze(1)
        best = _nearest_sq(block, ordered[pool_ids], block_ids, pool_ids, k_used, chunk_elements)
        result[order[start:stop]] = best.mean(dim=1)
    return result


def _morton_order(points: Tensor) -> Tensor:
    """Permutation [N] sorting points along a 3D Z-order curve over their bounding box."""
    low = points.amin(dim=0)
    span = (points.amax(dim=0) - low).clamp_min(1e-12)
    cells = (1 << MORTON_BITS) - 1
    quantised = ((points - low) / span * cells).round().to(torch.int64).clamp(0, cells)
    code = torch.zeros(points.shape[0], dtype=torch.int64, device=points.device)
    for axis in range(3):
        code |= _spread_bits(quantised[:, axis]) << axis
    return code.argsort()


def _spread_bits(values: Tensor) -> Tensor:
    """Insert two zero bits between each of the low 10 bits (Morton interleave helper)."""
    values = (values | (values << 16)) & 0x030000FF
    values = (values | (values << 8)) & 0x0300F00F
    values = (values | (values << 4)) & 0x030C30C3
    return (values | (values << 2)) & 0x09249249


def _nearest_sq(
    queries: Tensor, pool: Tensor, query_ids: Tensor, pool_ids: Tensor, k: int, chunk_elements: int
) -> Tensor:
    """Exact squared distances [Q,k] (ascending) to the k nearest pool points of other id."""
    n_candidates = min(pool.shape[0], k + EXTRA_CANDIDATES)
    rows_per_chunk = max(1, chunk_elements // max(1, pool.shape[0]))
    out = []
    for start in range(0, queries.shape[0], rows_per_chunk):
        stop = start + rows_per_chunk
        rows, row_ids = queries[start:stop], query_ids[start:stop]
        approx = torch.cdist(rows, pool)
        approx.masked_fill_(row_ids[:, None] == pool_ids[None, :], float("inf"))
        candidates = approx.topk(n_candidates, dim=1, largest=False).indices
        exact = (pool[candidates] - rows[:, None, :]).square().sum(dim=-1)
        exact.masked_fill_(pool_ids[candidates] == row_ids[:, None], float("inf"))
        out.append(exact.topk(k, dim=1, largest=False).values)
    return torch.cat(out)
