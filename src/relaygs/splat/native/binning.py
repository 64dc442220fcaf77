"""Binning through the native kernel: the torch path's TileBins, by a counting sort."""

from __future__ import annotations

import torch

from relaygs.splat.native.build import load
from relaygs.splat.tiles import DEFAULT_TILE_SIZE, TileBins


def bin_gaussians_native(
    bounds: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    tile_size: int = DEFAULT_TILE_SIZE,
) -> TileBins:
    """`relaygs.splat.tiles.bin_gaussians`'s lists, with `busy_tiles` (longest list first)
    in place of processing groups; reads nothing back to the host."""
    pair_gaussian, tile_start, tile_count, busy = load().bin_tiles(
        bounds.contiguous(), depths.contiguous(), visible.contiguous(), width, height, tile_size
    )
    return TileBins(
        tile_size,
        -(-width // tile_size),
        -(-height // tile_size),
        depths.shape[0],
        pair_gaussian,
        tile_start,
        tile_count,
        groups=[],
        busy_tiles=busy,
    )
