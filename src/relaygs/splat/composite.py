"""Front-to-back alpha compositing of binned 2D Gaussians with a hand-written backward.

Each tile group is a dense block [G, S, S, L] (tiles, pixel rows, pixel columns,
depth-ordered list). Transmittance comes from a cumulative product of (1 − α) along L,
so the 3DGS skip (α < 1/255) and early stop (T·(1 − α) < 1e-4) need no sequential loop.
The forward keeps two floats per pixel–Gaussian pair (exp(−power) and the masked
transmittance) when they fit a memory budget, else the backward recomputes them.
The backward gets Σ_{j>i} c_j α_j T_j from one more cumulative sum, the vectorised
form of the 3DGS backward's back-to-front walk.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from relaygs.splat.projection import ALPHA_MIN, Projection
from relaygs.splat.tiles import TileBins, TileGroup

ALPHA_MAX = 0.99
T_MIN = 1e-4
# Power given to pixels outside a Gaussian's box.
OUTSIDE_POWER = 1e30
# Powers are clamped here before exp: o·exp(−40) < 1/255 for any o <= 1, and exp stays
# out of the (slow) denormal range.
MAX_POWER = 40.0
# Per-pair state kept for the backward when the whole render needs at most this many bytes.
SAVE_BUDGET_BYTES = 1 << 30
# Columns of the packed per-Gaussian table gathered once per tile row.
_MX, _MY, _A, _B, _C, _O, _X0, _X1, _Y0, _Y1 = range(10)


@dataclass
class _Rows:
    """The depth-ordered Gaussian rows of one tile group, padded to its longest list."""

    tiles: torch.Tensor  # [G]
    gid: torch.Tensor  # [G,L] flat Gaussian index c*N + n
    valid: torch.Tensor  # [G,L]
    table: torch.Tensor  # [G,L,10] packed per-Gaussian values
    dx: torch.Tensor  # [G,1,S,L] pixel centre x − mean x
    dy: torch.Tensor  # [G,S,1,L] pixel centre y − mean y
    cols: torch.Tensor  # [G,S,1] pixel column indices of each tile (exact, table dtype)
    lines: torch.Tensor  # [G,S,1] pixel row indices


@dataclass
class _Pairs:
    """Per pixel–Gaussian quantities of one group (everything the backward needs)."""

    gauss: torch.Tensor  # [G,S,S,L] exp(−power)
    trans: torch.Tensor  # [G,S,S,L] T before the pair, 0 after the early stop


class _Scratch:
    """Grow-only flat buffers reused by every tile group of one render.

    Per-group temporaries are a few MB each; taking them from the system allocator on every
    group costs page faults that dominate cheap elementwise ops on CPU.
    """

    def __init__(self, like: torch.Tensor) -> None:
        self._like = like
        self._buffers: dict[str, torch.Tensor] = {}

    def take(self, name: str, shape: tuple[int, ...]) -> torch.Tensor:
        """A contiguous [shape] view of buffer `name` (contents undefined)."""
        size = math.prod(shape)
        buffer = self._buffers.get(name)
        if buffer is None or buffer.numel() < size:
            buffer = self._like.new_empty(size)
            self._buffers[name] = buffer
        return buffer[:size].view(shape)


def _gather_rows(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """table[index] for a 2D index, through index_select (much cheaper than advanced indexing)."""
    return table.index_select(0, index.reshape(-1)).view(*index.shape, *table.shape[1:])


def _rows(bins: TileBins, group: TileGroup, table: torch.Tensor) -> _Rows:
    """Gather the group's Gaussians and their offsets to the tile's pixel centres."""
    s = bins.tile_size
    tiles = group.tiles
    counts = bins.tile_count[tiles]
    steps = torch.arange(group.longest, device=tiles.device)
    valid = steps[None] < counts[:, None]
    rows = (bins.tile_start[tiles][:, None] + steps[None]).clamp(max=bins.pair_gaussian.numel() - 1)
    gid = bins.pair_gaussian.index_select(0, rows.reshape(-1)).view_as(rows)
    packed = _gather_rows(table, gid)
    ox, oy = bins.tile_origin(tiles)
    pix = torch.arange(s, device=tiles.device)
    cols = (ox[:, None] + pix[None]).to(table.dtype)[:, :, None]  # [G,S,1]
    lines = (oy[:, None] + pix[None]).to(table.dtype)[:, :, None]
    dx = (cols + 0.5 - packed[:, None, :, _MX]).unsqueeze(1)
    dy = (lines + 0.5 - packed[:, None, :, _MY]).unsqueeze(2)
    return _Rows(tiles, gid, valid, packed, dx, dy, cols, lines)


@functools.cache
def _below(value: float, dtype: torch.dtype) -> float:
    """The largest number of `dtype` below `value` (so `x > below` means `x >= value`)."""
    v = torch.tensor(value, dtype=dtype)
    return torch.nextafter(v, torch.zeros_like(v) - 1).item()


def _pairs(rows: _Rows, scratch: _Scratch, keep: bool) -> tuple[_Pairs, torch.Tensor]:
    """Evaluate every Gaussian of the group at every pixel of its tiles, front to back.

    Returns the pair state (fresh tensors when `keep`, else scratch views) and alpha (scratch).
    Masks are built from threshold/ceil arithmetic instead of boolean tensors: on CPU
    comparisons and `where` cost several times a multiply per element.
    """
    t = rows.table
    dtype = t.dtype
    shape = (rows.dy.shape[0], rows.dy.shape[1], rows.dx.shape[2], rows.dx.shape[3])
    in_x = (rows.cols >= t[:, None, :, _X0]) & (rows.cols <= t[:, None, :, _X1])  # [G,S,L]
    in_y = (rows.lines >= t[:, None, :, _Y0]) & (rows.lines <= t[:, None, :, _Y1])
    ex = torch.where(
        in_x[:, None], 0.5 * t[:, None, None, :, _A] * rows.dx * rows.dx, OUTSIDE_POWER
    )
    ey = torch.where(
        in_y[:, :, None], 0.5 * t[:, None, None, :, _C] * rows.dy * rows.dy, OUTSIDE_POWER
    )
    power = torch.add(ex, ey, out=scratch.take("power", shape))
    power.addcmul_(t[:, None, None, :, _B] * rows.dx, rows.dy)
    # 3DGS skips power < 0 (rounding): such pairs get MAX_POWER, whose alpha is < 1/255.
    F.threshold_(power, _below(0.0, dtype), MAX_POWER).clamp_(max=MAX_POWER).neg_()
    gauss = torch.exp(power, out=t.new_empty(shape) if keep else scratch.take("gauss", shape))

    _, alpha = _alpha(rows, gauss, scratch)
    one_minus = torch.neg(alpha, out=power).add_(1.0)
    # T before pair i is T_after[i] / (1 − α_i); zeroing T_after[i] < T_MIN first applies the
    # early stop. Skipped pairs (α = 0) keep a nonzero trans but carry no weight.
    trans = torch.cumprod(
        one_minus,
        dim=-1,
        out=t.new_empty(shape) if keep else scratch.take("trans", shape),
    )
    F.threshold_(trans, _below(T_MIN, dtype), 0.0).div_(one_minus)
    return _Pairs(gauss, trans), alpha


def _alpha(
    rows: _Rows, gauss: torch.Tensor, scratch: _Scratch
) -> tuple[torch.Tensor, torch.Tensor]:
    """o·exp(−power) and the composited alpha (0 below 1/255, clamped at 0.99), as scratch."""
    opacity = (rows.table[..., _O] * rows.valid)[:, None, None, :]
    alpha_raw = torch.mul(gauss, opacity, out=scratch.take("alpha_raw", gauss.shape))
    alpha = scratch.take("alpha", gauss.shape).copy_(alpha_raw)
    F.threshold_(alpha, _below(ALPHA_MIN, alpha.dtype), 0.0).clamp_(max=ALPHA_MAX)
    return alpha_raw, alpha


def _group_gradients(
    rows: _Rows,
    pairs: _Pairs,
    colors: torch.Tensor,
    grad_pix: torch.Tensor,
    k_pix: torch.Tensor,
    scratch: _Scratch,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-row gradients [G,L,6] (mean x/y, conic A/B/C, opacity) and of colours [G,L,D].

    colors [G,L,D] of the rows, grad_pix [G,P,D] and k_pix [G,S,S,1] of the group's pixels.
    """
    shape = pairs.gauss.shape
    g, p = grad_pix.shape[:2]
    alpha_raw, alpha = _alpha(rows, pairs.gauss, scratch)
    weight = torch.mul(alpha, pairs.trans, out=scratch.take("weight", shape))
    # v_i = g·c_i; suffix_i = Σ_{j>i} v_j w_j along the pixel's list.
    v = torch.bmm(grad_pix, colors.transpose(1, 2), out=scratch.take("v", (g, p, shape[-1])))
    v = v.view(shape)
    prod = torch.mul(v, weight, out=scratch.take("prod", shape))
    cum = torch.cumsum(prod, dim=-1, out=scratch.take("cum", shape))
    suffix = torch.sub(cum[..., -1:], cum, out=prod).add_(k_pix)
    denom = torch.neg(alpha, out=cum).add_(1.0)
    d_alpha = v.mul_(pairs.trans).sub_(suffix.div_(denom))
    # Only composited pairs (α > 0, trans > 0) below the 0.99 clamp pass a gradient.
    mask = torch.neg(alpha_raw, out=denom).add_(ALPHA_MAX)
    d_alpha.mul_(F.threshold_(mask, 0.0, 0.0).ceil_())
    d_alpha.mul_(torch.ceil(pairs.trans, out=mask)).mul_(torch.ceil(alpha, out=mask))
    d_opacity = torch.mul(d_alpha, pairs.gauss, out=prod).sum(dim=(1, 2))
    # power = ½A dx² + B dx dy + ½C dy² with dx = px − mx; d_power = −dL/dα · o·G.
    d_power = d_alpha.mul_(alpha_raw).neg_()
    gx = d_power.sum(dim=1, keepdim=True)  # [G,1,S,L]
    gy = d_power.sum(dim=2, keepdim=True)  # [G,S,1,L]
    gxy = torch.mul(d_power, rows.dy, out=prod).sum(dim=1, keepdim=True)
    s_xx = (gx * rows.dx * rows.dx).sum(dim=(1, 2))
    s_yy = (gy * rows.dy * rows.dy).sum(dim=(1, 2))
    s_xy = (gxy * rows.dx).sum(dim=(1, 2))
    s_x = (gx * rows.dx).sum(dim=(1, 2))
    s_y = (gy * rows.dy).sum(dim=(1, 2))
    a, b, c = rows.table[..., _A], rows.table[..., _B], rows.table[..., _C]
    grads = torch.stack(
        [-(a * s_x + b * s_y), -(b * s_x + c * s_y), 0.5 * s_xx, s_xy, 0.5 * s_yy, d_opacity],
        dim=-1,
    )
    d_cols = torch.bmm(weight.view(g, p, -1).transpose(1, 2), grad_pix)
    return grads, d_cols


def _to_tiles(image: torch.Tensor, bins: TileBins) -> torch.Tensor:
    """[C,H,W,D] image → [num_tiles, S·S, D] (zero-padded to whole tiles)."""
    c, h, w, d = image.shape
    s = bins.tile_size
    padded = image.new_zeros(c, bins.tiles_y * s, bins.tiles_x * s, d)
    padded[:, :h, :w] = image
    tiles = padded.reshape(c, bins.tiles_y, s, bins.tiles_x, s, d).permute(0, 1, 3, 2, 4, 5)
    return tiles.reshape(bins.num_tiles, s * s, d)


def _from_tiles(tiles: torch.Tensor, bins: TileBins, height: int, width: int) -> torch.Tensor:
    """[num_tiles, S·S, D] → [C,H,W,D] (crops the padding)."""
    s = bins.tile_size
    d = tiles.shape[-1]
    image = tiles.reshape(bins.num_cameras, bins.tiles_y, bins.tiles_x, s, s, d)
    image = image.permute(0, 1, 3, 2, 4, 5).reshape(
        bins.num_cameras, bins.tiles_y * s, bins.tiles_x * s, d
    )
    return image[:, :height, :width]


def _pack(
    means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor, bounds: torch.Tensor
) -> torch.Tensor:
    """[C·N, 10] table of everything a pair needs (box bounds are exact small integers)."""
    c, n = opacities.shape
    return torch.cat(
        [
            means2d.reshape(c * n, 2),
            conics.reshape(c * n, 3),
            opacities.reshape(c * n, 1),
            bounds.reshape(c * n, 4).to(means2d.dtype),
        ],
        dim=1,
    )


def _candidates(bins: TileBins) -> int:
    """Padded pixel–Gaussian candidates over all groups."""
    return sum(group.longest * group.tiles.numel() for group in bins.groups) * bins.tile_size**2


@dataclass
class FixedLayer:
    """Gaussians that stay unchanged between renders, with their own render into the cameras.

    `mask` [N] bool marks them; `colors` [C,H,W,D] and `alphas` [C,H,W,1] are their render
    alone (RGB, no background). A tile only they touch is copied from it instead of
    composited and gets no backward pass; fixed Gaussians get zero gradients. `projection`
    and `features` [C,F,D] (F = mask.sum(), in row order), when given, are the fixed rows'
    projection and colours from that render (`meta`), so they are not computed again.
    """

    mask: torch.Tensor
    colors: torch.Tensor
    alphas: torch.Tensor
    projection: Projection | None = None
    features: torch.Tensor | None = None


class CompositeGaussians(torch.autograd.Function):
    """colors [C,H,W,D] and alphas [C,H,W,1] from binned screen-space Gaussians.

    Only the tiles of `bins.groups` are composited (and differentiated); with a FixedLayer
    `fixed`, every other tile is copied from its render, else it is empty.
    """

    @staticmethod
    def forward(
        ctx: Any,
        means2d: torch.Tensor,
        conics: torch.Tensor,
        opacities: torch.Tensor,
        colors: torch.Tensor,
        backgrounds: torch.Tensor | None,
        bounds: torch.Tensor,
        bins: TileBins,
        width: int,
        height: int,
        fixed: FixedLayer | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Composite tile group by group, keeping the pairs for backward if they fit the budget."""
        c, n, d = colors.shape
        table = _pack(means2d.detach(), conics.detach(), opacities.detach(), bounds)
        flat_colors = colors.detach().reshape(c * n, d)
        p = bins.tile_size**2
        keep_pairs = any(ctx.needs_input_grad) and (
            _candidates(bins) * 2 * table.element_size() <= SAVE_BUDGET_BYTES
        )
        saved = []
        scratch = _Scratch(table)
        if fixed is None:
            color_tiles = colors.new_zeros(bins.num_tiles, p, d)
            coverage = colors.new_zeros(bins.num_tiles, p)
        else:
            color_tiles = _to_tiles(fixed.colors.detach(), bins)
            coverage = _to_tiles(fixed.alphas.detach(), bins)[..., 0]
        for group in bins.groups:
            tiles = group.tiles
            rows = _rows(bins, group, table)
            pairs, alpha = _pairs(rows, scratch, keep_pairs)
            weight = alpha.mul_(pairs.trans).view(tiles.numel(), p, -1)
            color_tiles[tiles] = torch.bmm(weight, _gather_rows(flat_colors, rows.gid))
            # Σ α_i T_i telescopes to 1 − T_N over the composited pairs.
            coverage[tiles] = weight.sum(-1)
            if keep_pairs:
                saved.append(pairs)
        t_final = _from_tiles((1.0 - coverage)[..., None], bins, height, width)
        out = _from_tiles(color_tiles, bins, height, width)
        if backgrounds is not None:
            out = out + t_final * backgrounds[:, None, None, :]
        ctx.bins = bins
        ctx.fixed = None if fixed is None else fixed.mask
        ctx.saved_pairs = saved
        ctx.save_for_backward(means2d, conics, opacities, colors, backgrounds, bounds, t_final)
        return out, 1.0 - t_final

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(
        ctx: Any, grad_colors: torch.Tensor, grad_alphas: torch.Tensor
    ) -> tuple[torch.Tensor | None, ...]:
        """Gradients for means2d, conics, opacities, colors and backgrounds, tile group by group."""
        means2d, conics, opacities, colors, backgrounds, bounds, t_final = ctx.saved_tensors
        bins: TileBins = ctx.bins
        c, n, d = colors.shape
        s = bins.tile_size
        table = _pack(means2d, conics, opacities, bounds)
        flat_colors = colors.reshape(c * n, d)

        pixel_k, grad_bg = background_terms(grad_colors, grad_alphas, t_final, backgrounds)
        g_tiles = _to_tiles(grad_colors, bins)
        k_tiles = _to_tiles(pixel_k, bins)[..., 0]

        # Per-Gaussian gradient table: mean x/y, conic A/B/C, opacity.
        grad_table = table.new_zeros(c * n, 6)
        grad_cols = torch.zeros_like(flat_colors)
        scratch = _Scratch(table)
        for index, group in enumerate(bins.groups):
            tiles = group.tiles
            rows = _rows(bins, group, table)
            pairs = ctx.saved_pairs[index] if ctx.saved_pairs else _pairs(rows, scratch, False)[0]
            grads, d_cols = _group_gradients(
                rows,
                pairs,
                _gather_rows(flat_colors, rows.gid),
                g_tiles.index_select(0, tiles),
                k_tiles.index_select(0, tiles).view(tiles.numel(), s, s, 1),
                scratch,
            )
            # Padding rows have zero gradients, so they can be added at their clamped index.
            grad_table.index_add_(0, rows.gid.reshape(-1), grads.reshape(-1, 6))
            grad_cols.index_add_(0, rows.gid.reshape(-1), d_cols.reshape(-1, d))
        ctx.saved_pairs = None
        return input_gradients(
            grad_table, grad_cols, ctx.fixed, (means2d, conics, opacities, colors), grad_bg
        )


def background_terms(
    grad_colors: torch.Tensor,
    grad_alphas: torch.Tensor,
    t_final: torch.Tensor,
    backgrounds: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Per pixel K = T_N·(g·bg) − g_alpha·T_N [C,H,W,1], what every α_i changes through T_N,
    and the backgrounds' gradient [C,D] (None without backgrounds)."""
    pixel_k = -grad_alphas * t_final
    if backgrounds is None:
        return pixel_k, None
    pixel_k = pixel_k + t_final * (grad_colors * backgrounds[:, None, None, :]).sum(-1, True)
    return pixel_k, (grad_colors * t_final).sum(dim=(1, 2))


def input_gradients(
    grad_table: torch.Tensor,
    grad_cols: torch.Tensor,
    fixed: torch.Tensor | None,
    inputs: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    grad_bg: torch.Tensor | None,
) -> tuple[torch.Tensor | None, ...]:
    """A compositing Function's backward result from per-Gaussian gradients [C·N,6] (mean
    x/y, conic A/B/C, opacity) and of colours [C·N,D]: rows of `fixed` [N] zeroed, shaped as
    `inputs` (means2d, conics, opacities, colors), None for the non-tensor arguments."""
    means2d, conics, opacities, colors = inputs
    c, n, d = colors.shape
    if fixed is not None:
        grad_table.view(c, n, 6).masked_fill_(fixed[None, :, None], 0.0)
        grad_cols.view(c, n, d).masked_fill_(fixed[None, :, None], 0.0)
    return (
        grad_table[:, 0:2].reshape_as(means2d),
        grad_table[:, 2:5].reshape_as(conics),
        grad_table[:, 5].reshape_as(opacities),
        grad_cols.reshape_as(colors),
        grad_bg,
        None,
        None,
        None,
        None,
        None,
    )
