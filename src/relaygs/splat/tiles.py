"""Bin screen-space Gaussians into square pixel tiles, depth-ordered: pairs sort on tile id alone.

Gaussians are sorted by depth once per camera; each visible one is expanded into the
tiles its pixel box touches; a stable sort on the (small) tile id keeps depth order
inside every tile. Tiles are then grouped by list length so the compositor works on
dense, padded [G, pixels, L] blocks of bounded size.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

DEFAULT_TILE_SIZE = 8
# Upper bound on pixel–Gaussian candidates per processing group (memory and cache).
GROUP_BUDGET = 1 << 19
# A group stops growing when list lengths drop below this fraction of its longest.
GROUP_FILL = 0.75


@dataclass(frozen=True)
class TileGroup:
    """Tiles composited together, and the longest of their lists: known on the host, so
    sizing the group's padded block does not wait for the device."""

    tiles: torch.Tensor  # tile ids
    longest: int


@dataclass
class TileBins:
    """Depth-sorted Gaussian lists per tile, over all cameras, plus processing groups."""

    tile_size: int
    tiles_x: int
    tiles_y: int
    num_cameras: int
    pair_gaussian: torch.Tensor  # [M] flat index c*N + n, grouped by tile, front to back
    tile_start: torch.Tensor  # [num_tiles] offset of each tile's list in pair_gaussian
    tile_count: torch.Tensor  # [num_tiles] list length
    groups: list[TileGroup]  # tiles processed together, lists of similar length (torch path)
    # tiles to composite, longest list first (native, triton)
    busy_tiles: torch.Tensor | None = None

    @property
    def num_tiles(self) -> int:
        """Tiles over all cameras."""
        return self.num_cameras * self.tiles_x * self.tiles_y

    def tile_origin(self, tiles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pixel x, y of the top-left corner of each tile id."""
        local = tiles % (self.tiles_x * self.tiles_y)
        return (local % self.tiles_x) * self.tile_size, (local // self.tiles_x) * self.tile_size


def bin_gaussians(
    bounds: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    tile_size: int = DEFAULT_TILE_SIZE,
) -> TileBins:
    """Build per-tile front-to-back lists from pixel boxes [C,N,4] (x0, x1, y0, y1)."""
    bins = _tile_lists(bounds, depths, visible, width, height, tile_size)
    return replace(bins, groups=_group_tiles(bins.tile_count, tile_size * tile_size))


def bin_gaussians_all_tiles(
    bounds: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    tile_size: int = DEFAULT_TILE_SIZE,
) -> TileBins:
    """`bin_gaussians`'s lists with `busy_tiles` holding every tile, longest list first (the
    empty ones last, so its length is known without a device read), and no groups."""
    bins = _tile_lists(bounds, depths, visible, width, height, tile_size)
    busy = torch.argsort(bins.tile_count, descending=True, stable=True)
    return replace(bins, busy_tiles=busy)


def _tile_lists(
    bounds: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    tile_size: int,
) -> TileBins:
    """The per-tile lists alone (no groups, no busy tiles)."""
    num_cameras, n = depths.shape
    device = depths.device
    tiles_x = -(-width // tile_size)
    tiles_y = -(-height // tile_size)
    per_camera = tiles_x * tiles_y

    masked_depth = torch.where(visible, depths, torch.full_like(depths, float("inf")))
    order = torch.argsort(masked_depth, dim=1, stable=True)
    sorted_visible = torch.gather(visible, 1, order)
    cam_index = torch.arange(num_cameras, device=device)[:, None].expand(-1, n)
    flat = (cam_index * n + order)[sorted_visible]
    cams = cam_index[sorted_visible]
    box = bounds.reshape(-1, 4)[flat].long()

    tx0, tx1 = box[:, 0] // tile_size, box[:, 1] // tile_size
    ty0, ty1 = box[:, 2] // tile_size, box[:, 3] // tile_size
    ntx = tx1 - tx0 + 1
    counts = ntx * (ty1 - ty0 + 1)
    total = int(counts.sum())
    owner = torch.repeat_interleave(
        torch.arange(flat.numel(), device=device), counts, output_size=total
    )
    first = torch.cumsum(counts, 0) - counts
    local = torch.arange(total, device=device) - first[owner]
    tx = tx0[owner] + local % ntx[owner]
    ty = ty0[owner] + local // ntx[owner]
    tile_id = cams[owner] * per_camera + ty * tiles_x + tx
    tile_id, perm = torch.sort(tile_id, stable=True)
    pair_gaussian = flat[owner[perm]]

    num_tiles = num_cameras * per_camera
    tile_count = torch.bincount(tile_id, minlength=num_tiles)
    tile_start = torch.cumsum(tile_count, 0) - tile_count
    return TileBins(
        tile_size, tiles_x, tiles_y, num_cameras, pair_gaussian, tile_start, tile_count, []
    )


def tiles_touched_by(bins: TileBins, rows: torch.Tensor) -> torch.Tensor:
    """[num_tiles] bool: tiles whose list holds at least one Gaussian n with rows[n] true."""
    n = rows.numel()
    hits = rows[bins.pair_gaussian % n].to(torch.int64)
    # Lists are contiguous: the hits of tile t are ends[t] − ends[t − 1] of a running sum.
    ends = torch.cumsum(hits, 0)
    before = torch.cat([ends.new_zeros(1), ends])
    start = bins.tile_start
    return before[start + bins.tile_count] > before[start]


def only_tiles(bins: TileBins, tiles: torch.Tensor) -> TileBins:
    """The bins with processing groups (or busy tiles) only where `tiles` [num_tiles] is true."""
    if bins.busy_tiles is not None:
        return replace(bins, busy_tiles=bins.busy_tiles[tiles[bins.busy_tiles]])
    counts = torch.where(tiles, bins.tile_count, torch.zeros_like(bins.tile_count))
    return replace(bins, groups=_group_tiles(counts, bins.tile_size**2))


def _group_tiles(tile_count: torch.Tensor, pixels: int) -> list[TileGroup]:
    """Split non-empty tiles, longest lists first, into groups of bounded padded size."""
    by_length = torch.argsort(tile_count, descending=True, stable=True)
    lengths = tile_count[by_length].tolist()
    groups = []
    start = 0
    while start < len(lengths) and lengths[start] > 0:
        longest = lengths[start]
        end = start + max(1, GROUP_BUDGET // (longest * pixels))
        end = min(end, len(lengths))
        floor = longest * GROUP_FILL
        # lengths are non-increasing: cut where they fall below the fill floor or reach 0.
        cut = start + 1
        hi = end
        while cut < hi:
            mid = (cut + hi) // 2
            if lengths[mid] >= floor and lengths[mid] > 0:
                cut = mid + 1
            else:
                hi = mid
        groups.append(TileGroup(by_length[start:cut], longest))
        start = cut
    return groups
