"""Compositing through the native CPU kernel, same contract as
`composite.CompositeGaussians`: one fused pass per tile forward, one back-to-front pass per
tile backward that recomputes each pair instead of storing it."""

from __future__ import annotations

from typing import Any

import torch

from relaygs.splat.composite import FixedLayer, input_gradients
from relaygs.splat.kernel_io import (
    backward_inputs,
    finish_forward,
    forward_buffers,
    geometry,
    kernel_inputs,
)
from relaygs.splat.native.build import load
from relaygs.splat.tiles import TileBins


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
        inputs = kernel_inputs(means2d, conics, opacities, colors, bounds)
        out, t_final, last = forward_buffers(colors, width, height, fixed)
        ctx.tiles = bins.busy_tiles
        load().composite_forward(
            inputs.table, inputs.colors, bins.pair_gaussian, bins.tile_start, bins.tile_count,
            ctx.tiles, *geometry(bins, width, height), out, t_final, last,
        )  # fmt: skip
        saved = (means2d, conics, opacities, colors, bounds)
        return finish_forward(ctx, out, t_final, last, saved, backgrounds, bins, fixed)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(
        ctx: Any, grad_colors: torch.Tensor, grad_alphas: torch.Tensor
    ) -> tuple[torch.Tensor | None, ...]:
        """Per-pair gradients from the kernel, added into per-Gaussian ones in pair order."""
        saved, inputs, pixel_k, grad_bg = backward_inputs(ctx, grad_colors, grad_alphas)
        means2d, conics, opacities, colors, _, t_final, last = saved
        bins: TileBins = ctx.bins
        grad_table, grad_cols = load().composite_backward(
            inputs.table, inputs.colors, bins.pair_gaussian, bins.tile_start, bins.tile_count,
            ctx.tiles, *geometry(bins, grad_colors.shape[2], grad_colors.shape[1]),
            grad_colors.contiguous(), pixel_k, t_final[..., 0].contiguous(), last,
        )  # fmt: skip
        return input_gradients(
            grad_table, grad_cols, ctx.fixed, (means2d, conics, opacities, colors), grad_bg
        )
