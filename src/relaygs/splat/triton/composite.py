"""Compositing through the Triton kernels, same contract as
`relaygs.splat.composite.CompositeGaussians`: one fused front-to-back pass per tile forward,
one back-to-front pass per tile backward that recomputes each pair instead of storing it."""

from __future__ import annotations

from dataclasses import dataclass
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
from relaygs.splat.tiles import TileBins

MAX_PIXELS = 256  # lanes per program: a larger tile is split over several programs
# Values in a program's widest temporary ([pixels, batch, channels]). Set from the compiled
# kernels' registers on sm_90 (8×8 tiles, RGB: forward 122, backward 149, no spills; twice
# these batches take 206 and 249), not from timings: none were made on a GPU yet.
FORWARD_ELEMENTS = 4096
BACKWARD_ELEMENTS = 2048
# Triton's default, named (its 3.9 warns while it is left unset): multiply-adds fused, as nvcc.
COMPILE_OPTIONS = {"enable_fp_fusion": True}


@dataclass(frozen=True)
class Launch:
    """A kernel launch's grid and block sizes (powers of two) for one render."""

    grid: tuple[int, int]
    pixels: int
    batch: int
    channels: int

    def sizes(self) -> dict[str, int]:
        """The kernels' compile-time block sizes."""
        return {"PIXELS": self.pixels, "BATCH": self.batch, "CHANNELS": self.channels}


def launch_for(bins: TileBins, tiles: torch.Tensor, channels: int, elements: int) -> Launch:
    """One program per (tile, block of its pixels); batches of Gaussians as wide as a
    [pixels, batch, channels] temporary of at most `elements` values allows (4 to 32)."""
    area = bins.tile_size**2
    pixels = min(MAX_PIXELS, _power_of_2_at_least(area))
    padded = _power_of_2_at_least(channels)
    room = max(1, elements // (pixels * padded))
    batch = min(32, max(4, 1 << (room.bit_length() - 1)))
    return Launch((tiles.numel(), -(-area // pixels)), pixels, batch, padded)


def _power_of_2_at_least(value: int) -> int:
    return 1 << max(0, value - 1).bit_length()


class TritonCompositeGaussians(torch.autograd.Function):
    """colors [C,H,W,D] and alphas [C,H,W,1], composited by the Triton kernels."""

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
        from relaygs.splat.triton.kernels import composite_forward_kernel

        inputs = kernel_inputs(means2d, conics, opacities, colors, bounds)
        out, t_final, last = forward_buffers(colors, width, height, fixed)
        tiles = ctx.tiles = bins.busy_tiles
        d = colors.shape[2]
        launch = launch_for(bins, tiles, d, FORWARD_ELEMENTS)
        if tiles.numel() > 0:
            composite_forward_kernel[launch.grid](
                inputs.table, inputs.colors, bins.pair_gaussian, bins.tile_start,
                bins.tile_count, tiles, out, t_final, last, *geometry(bins, width, height), d,
                **launch.sizes(), **COMPILE_OPTIONS,
            )  # fmt: skip
        saved = (means2d, conics, opacities, colors, bounds)
        return finish_forward(ctx, out, t_final, last, saved, backgrounds, bins, fixed)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(
        ctx: Any, grad_colors: torch.Tensor, grad_alphas: torch.Tensor
    ) -> tuple[torch.Tensor | None, ...]:
        """Per-Gaussian gradients, each pair's added in by the kernel (atomics: the order of
        the additions, and so the last bits of the sums, may differ between runs on a GPU)."""
        from relaygs.splat.triton.kernels import GRAD_COLUMNS, composite_backward_kernel

        saved, inputs, pixel_k, grad_bg = backward_inputs(ctx, grad_colors, grad_alphas)
        means2d, conics, opacities, colors, _, t_final, last = saved
        bins: TileBins = ctx.bins
        d = colors.shape[2]
        height, width = grad_colors.shape[1:3]
        grad_table = inputs.table.new_zeros(inputs.table.shape[0], GRAD_COLUMNS.value)
        grad_cols = torch.zeros_like(inputs.colors)
        launch = launch_for(bins, ctx.tiles, d, BACKWARD_ELEMENTS)
        if ctx.tiles.numel() > 0:
            composite_backward_kernel[launch.grid](
                inputs.table, inputs.colors, bins.pair_gaussian, bins.tile_start,
                bins.tile_count, ctx.tiles, grad_colors.contiguous(), pixel_k,
                t_final[..., 0].contiguous(), last, grad_table, grad_cols,
                *geometry(bins, width, height), d, **launch.sizes(), **COMPILE_OPTIONS,
            )  # fmt: skip
        return input_gradients(
            grad_table, grad_cols, ctx.fixed, (means2d, conics, opacities, colors), grad_bg
        )
