"""Compositing through the native CPU kernel, same contract as
`composite.CompositeGaussians`: one fused pass per tile forward, one back-to-front pass per
tile backward that recomputes each pair instead of storing it."""

from __future__ import annotations

from typing import Any

import torch

from relaygs.splat.composite import FixedLayer, _pack, background_terms, input_gradients
from relaygs.splat.native.build import load
from relaygs.splat.tiles import TileBins


def _geometry(bins: TileBins, width: int, height: int) -> tuple[int, ...]:
    return bins.tile_size, bins.tiles_x, bins.tiles_y, width, height


class NativeCompositeGaussians(torch.autograd.Function):
    """colors [C,H,W,D] and alphas [C,H,W,1], composited by the native kernel."""

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
        """Composite `bins.busy_tiles`; other tiles keep the fixed layer's render (or nothing)."""
        kernel = load()
        c, n, d = colors.shape
        table = _pack(means2d.detach(), conics.detach(), opacities.detach(), bounds).contiguous()
        flat_colors = colors.detach().reshape(c * n, d).contiguous()
        tiles = bins.busy_tiles
        if fixed is None:
            out = colors.new_zeros(c, height, width, d)
            t_final = colors.new_ones(c, height, width)
        else:
            out = fixed.colors.detach().to(colors.dtype).contiguous().clone()
            t_final = (1.0 - fixed.alphas.detach().to(colors.dtype))[..., 0].contiguous()
        last = torch.full((c, height, width), -1, dtype=torch.int32)
        kernel.composite_forward(
            table, flat_colors, bins.pair_gaussian, bins.tile_start, bins.tile_count, tiles,
            *_geometry(bins, width, height), out, t_final, last,
        )  # fmt: skip
        t_final = t_final[..., None]
        if backgrounds is not None:
            out = out + t_final * backgrounds[:, None, None, :]
        ctx.bins = bins
        ctx.tiles = tiles
        ctx.fixed = None if fixed is None else fixed.mask
        ctx.save_for_backward(
            means2d, conics, opacities, colors, backgrounds, bounds, t_final, last
        )
        return out, 1.0 - t_final

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(
        ctx: Any, grad_colors: torch.Tensor, grad_alphas: torch.Tensor
    ) -> tuple[torch.Tensor | None, ...]:
        """Per-pair gradients from the kernel, added into per-Gaussian ones in pair order."""
        means2d, conics, opacities, colors, backgrounds, bounds, t_final, last = ctx.saved_tensors
        bins: TileBins = ctx.bins
        c, n, d = colors.shape
        table = _pack(means2d, conics, opacities, bounds).contiguous()
        flat_colors = colors.reshape(c * n, d).contiguous()
        pixel_k, grad_bg = background_terms(grad_colors, grad_alphas, t_final, backgrounds)
        grad_table, grad_cols = load().composite_backward(
            table, flat_colors, bins.pair_gaussian, bins.tile_start, bins.tile_count, ctx.tiles,
            *_geometry(bins, grad_colors.shape[2], grad_colors.shape[1]),
            grad_colors.contiguous(), pixel_k[..., 0].contiguous(), t_final[..., 0].contiguous(),
            last,
        )  # fmt: skip
        return input_gradients(
            grad_table, grad_cols, ctx.fixed, (means2d, conics, opacities, colors), grad_bg
        )
