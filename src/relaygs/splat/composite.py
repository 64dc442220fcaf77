"""Front-to-back alpha compositing of binned 2D Gaussians with a hand-written backward.

Each tile group is a dense block [G, P, L] (tiles, pixels per tile, depth-ordered list).
Transmittance comes from a cumulative sum of log(1 − α) along L, so inclusion and
early stop (3DGS: a Gaussian is skipped once T·(1 − α) < 1e-4) need no sequential loop.
The backward recomputes each block instead of keeping per-pair tensors, and gets the
suffix sums Σ_{j>i} c_j α_j T_j from one more cumulative sum, as the 3DGS backward does
when it walks from back to front.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from relaygs.splat.projection import ALPHA_MIN
from relaygs.splat.tiles import TileBins

ALPHA_MAX = 0.99
T_MIN = 1e-4
LOG_T_MIN = math.log(T_MIN)
# Power assigned to pixels outside a Gaussian's box.
OUTSIDE_POWER = 1e30
# Powers are clamped here before exp: o·exp(−40) < 1/255 for any o <= 1.
MAX_POWER = 40.0


@dataclass
class _Block:
    """Recomputed per-pair quantities of one tile group."""

    gid: torch.Tensor  # [G,L] flat Gaussian index
    row_valid: torch.Tensor  # [G,L]
    dx: torch.Tensor  # [G,1,S,L] pixel centre x − mean x
    dy: torch.Tensor  # [G,S,1,L]
    gauss: torch.Tensor  # [G,S,S,L] exp(−power)
    alpha_raw: torch.Tensor  # [G,S,S,L] o·exp(−power)
    alpha: torch.Tensor  # [G,S,S,L] clamped, 0 where skipped
    log_trans: torch.Tensor  # [G,S,S,L] log(1 − α)
    cum: torch.Tensor  # [G,S,S,L] inclusive Σ log(1 − α)
    included: torch.Tensor  # [G,S,S,L] bool: composited (not skipped, before early stop)


def _block(
    bins: TileBins,
    tiles: torch.Tensor,
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    bounds: torch.Tensor,
) -> _Block:
    """Evaluate every Gaussian of the group's tiles at every pixel of those tiles."""
    s = bins.tile_size
    counts = bins.tile_count[tiles]
    length = int(counts.max())
    steps = torch.arange(length, device=tiles.device)
    row_valid = steps[None] < counts[:, None]
    rows = (bins.tile_start[tiles][:, None] + steps[None]).clamp(max=bins.pair_gaussian.numel() - 1)
    gid = bins.pair_gaussian[rows]

    ox, oy = bins.tile_origin(tiles)
    pix = torch.arange(s, device=tiles.device)
    pix_x = (ox[:, None] + pix[None])[:, :, None]  # [G,S,1] integer pixel columns
    pix_y = (oy[:, None] + pix[None])[:, :, None]
    px = pix_x.to(means2d.dtype) + 0.5  # pixel centres
    py = pix_y.to(means2d.dtype) + 0.5
    m = means2d[gid]  # [G,L,2]
    dx = (px - m[:, None, :, 0]).unsqueeze(1)  # [G,1,S,L]
    dy = (py - m[:, None, :, 1]).unsqueeze(2)  # [G,S,1,L]
    con = conics[gid]
    a, b, c = (con[:, None, None, :, k] for k in range(3))

    box = bounds[gid]  # [G,L,4]
    in_x = (pix_x >= box[:, None, :, 0]) & (pix_x <= box[:, None, :, 1])  # [G,S,L]
    in_y = (pix_y >= box[:, None, :, 2]) & (pix_y <= box[:, None, :, 3])
    ex = torch.where(in_x.unsqueeze(1), 0.5 * a * dx * dx, OUTSIDE_POWER)
    ey = torch.where(in_y.unsqueeze(2), 0.5 * c * dy * dy, OUTSIDE_POWER)
    power = torch.addcmul(ex + ey, b * dx, dy)
    # 3DGS skips power < 0 (rounding); a clamped power of MAX_POWER gives alpha < 1/255, so
    # both cases drop out through the alpha test, and exp never enters the slow denormal path.
    power.clamp_(max=MAX_POWER).masked_fill_(power < 0, MAX_POWER)

    opac = torch.where(row_valid, opacities[gid], 0.0)[:, None, None, :]
    gauss = power.neg_().exp_()
    alpha_raw = gauss * opac
    keep = alpha_raw >= ALPHA_MIN
    alpha = alpha_raw.clamp(max=ALPHA_MAX).mul_(keep)
    log_trans = torch.log1p(-alpha)
    cum = torch.cumsum(log_trans, dim=-1)
    included = (cum >= LOG_T_MIN).logical_and_(keep)
    return _Block(gid, row_valid, dx, dy, gauss, alpha_raw, alpha, log_trans, cum, included)


def _transmittance(blk: _Block) -> torch.Tensor:
    """T_i before each pair; clamped far below T_MIN where it no longer matters."""
    return (blk.cum - blk.log_trans).clamp_(min=-MAX_POWER).exp_()


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


class CompositeGaussians(torch.autograd.Function):
    """colors [C,H,W,D] and alphas [C,H,W,1] from binned screen-space Gaussians."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, backgrounds, bounds, bins, width, height):
        c, n, d = colors.shape
        flat_means = means2d.reshape(c * n, 2)
        flat_conics = conics.reshape(c * n, 3)
        flat_opac = opacities.reshape(c * n)
        flat_colors = colors.reshape(c * n, d)
        flat_bounds = bounds.reshape(c * n, 4)
        p = bins.tile_size**2
        color_tiles = colors.new_zeros(bins.num_tiles, p, d)
        coverage = colors.new_zeros(bins.num_tiles, p)
        for tiles in bins.groups:
            blk = _block(bins, tiles, flat_means, flat_conics, flat_opac, flat_bounds)
            g = tiles.numel()
            weight = _transmittance(blk).mul_(blk.alpha).mul_(blk.included)
            color_tiles[tiles] = torch.bmm(weight.reshape(g, p, -1), flat_colors[blk.gid])
            # Σ α_i T_i telescopes to 1 − T_N over the composited pairs.
            coverage[tiles] = weight.sum(-1).reshape(g, p)
        t_final = _from_tiles((1.0 - coverage)[..., None], bins, height, width)
        out = _from_tiles(color_tiles, bins, height, width)
        if backgrounds is not None:
            out = out + t_final * backgrounds[:, None, None, :]
        ctx.bins = bins
        ctx.size = (width, height)
        ctx.save_for_backward(means2d, conics, opacities, colors, backgrounds, bounds, t_final)
        return out, 1.0 - t_final

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_colors, grad_alphas):
        means2d, conics, opacities, colors, backgrounds, bounds, t_final = ctx.saved_tensors
        bins: TileBins = ctx.bins
        c, n, d = colors.shape
        p = bins.tile_size**2
        flat_means = means2d.reshape(c * n, 2)
        flat_conics = conics.reshape(c * n, 3)
        flat_opac = opacities.reshape(c * n)
        flat_colors = colors.reshape(c * n, d)
        flat_bounds = bounds.reshape(c * n, 4)

        # Per pixel: K = T_N·(g·bg) − g_alpha·T_N collects what every α_i changes via T_N.
        pixel_k = -grad_alphas * t_final
        grad_bg = None
        if backgrounds is not None:
            pixel_k = pixel_k + t_final * (grad_colors * backgrounds[:, None, None, :]).sum(-1, True)
            grad_bg = (grad_colors * t_final).sum(dim=(1, 2))
        g_tiles = _to_tiles(grad_colors, bins)
        k_tiles = _to_tiles(pixel_k, bins)[..., 0]

        grad_means = torch.zeros_like(flat_means)
        grad_conics = torch.zeros_like(flat_conics)
        grad_opac = torch.zeros_like(flat_opac)
        grad_cols = torch.zeros_like(flat_colors)
        s = bins.tile_size
        for tiles in bins.groups:
            blk = _block(bins, tiles, flat_means, flat_conics, flat_opac, flat_bounds)
            g = tiles.numel()
            trans = _transmittance(blk)
            weight = (blk.alpha * trans).mul_(blk.included)
            grad_pix = g_tiles[tiles]  # [G,P,D]
            cols = flat_colors[blk.gid]  # [G,L,D]
            # v_i = g·c_i; suffix_i = Σ_{j>i} v_j w_j within the pixel's list.
            v = torch.bmm(grad_pix, cols.transpose(1, 2)).reshape_as(weight)
            vw_cum = torch.cumsum(v * weight, dim=-1)
            suffix = vw_cum[..., -1:] - vw_cum
            k_pix = k_tiles[tiles].reshape(g, s, s, 1)
            d_alpha = v * trans - (suffix + k_pix) / (1.0 - blk.alpha)
            live = blk.included & (blk.alpha_raw < ALPHA_MAX)
            d_alpha = torch.where(live, d_alpha, 0.0)
            d_opac = (d_alpha * blk.gauss).sum(dim=(1, 2))
            d_power = -d_alpha * blk.alpha_raw  # [G,S,S,L]
            gx = d_power.sum(dim=1, keepdim=True)  # [G,1,S,L] summed over pixel rows
            gy = d_power.sum(dim=2, keepdim=True)  # [G,S,1,L] summed over pixel columns
            gxy = (d_power * blk.dy).sum(dim=1, keepdim=True)
            s_xx = (gx * blk.dx * blk.dx).sum(dim=(1, 2))
            s_yy = (gy * blk.dy * blk.dy).sum(dim=(1, 2))
            s_xy = (gxy * blk.dx).sum(dim=(1, 2))
            s_x = (gx * blk.dx).sum(dim=(1, 2))
            s_y = (gy * blk.dy).sum(dim=(1, 2))
            con = flat_conics[blk.gid]
            a, b, cc = con[..., 0], con[..., 1], con[..., 2]
            # power = ½A dx² + B dx dy + ½C dy² with dx = px − mx.
            d_mean = torch.stack([-(a * s_x + b * s_y), -(b * s_x + cc * s_y)], dim=-1)
            d_conic = torch.stack([0.5 * s_xx, s_xy, 0.5 * s_yy], dim=-1)
            d_cols = torch.bmm(weight.reshape(g, p, -1).transpose(1, 2), grad_pix)

            rows = blk.row_valid
            idx = blk.gid[rows]
            grad_means.index_add_(0, idx, d_mean[rows])
            grad_conics.index_add_(0, idx, d_conic[rows])
            grad_opac.index_add_(0, idx, d_opac[rows])
            grad_cols.index_add_(0, idx, d_cols[rows])
        return (
            grad_means.reshape_as(means2d),
            grad_conics.reshape_as(conics),
            grad_opac.reshape_as(opacities),
            grad_cols.reshape_as(colors),
            grad_bg,
            None,
            None,
            None,
            None,
        )
