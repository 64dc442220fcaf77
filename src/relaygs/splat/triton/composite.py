"""Compositing through the Triton kernels, same contract as
`relaygs.splat.composite.CompositeGaussians`: one fused front-to-back pass per tile forward,
one back-to-front pass per tile backward that recomputes each pair instead of storing it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from relaygs.splat.composite import FixedLayer, _pack, background_terms, input_gradients
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


def _geometry(bins: TileBins, width: int, height: int) -> tuple[int, ...]:
    return bins.tile_size, bins.tiles_x, bins.tiles_y, width, height


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
        last = torch.full((c, height, width), -1, dtype=torch.int32, device=colors.device)
        launch = launch_for(bins, tiles, d, FORWARD_ELEMENTS)
        if tiles.numel() > 0:
            composite_forward_kernel[launch.grid](
                table, flat_colors, bins.pair_gaussian, bins.tile_start, bins.tile_count, tiles,
                out, t_final, last, *_geometry(bins, width, height), d,
                **launch.sizes(), **COMPILE_OPTIONS,
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
        """Per-Gaussian gradients, each pair's added in by the kernel (atomics: the order of
        the additions, and so the last bits of the sums, may differ between runs on a GPU)."""
        from relaygs.splat.triton.kernels import GRAD_COLUMNS, composite_backward_kernel

        means2d, conics, opacities, colors, backgrounds, bounds, t_final, last = ctx.saved_tensors
        bins: TileBins = ctx.bins
        c, n, d = colors.shape
        height, width = grad_colors.shape[1:3]
        table = _pack(means2d, conics, opacities, bounds).contiguous()
        flat_colors = colors.reshape(c * n, d).contiguous()
        pixel_k, grad_bg = background_terms(grad_colors, grad_alphas, t_final, backgrounds)
        grad_table = table.new_zeros(c * n, GRAD_COLUMNS.value)
        grad_cols = torch.zeros_like(flat_colors)
        launch = launch_for(bins, ctx.tiles, d, BACKWARD_ELEMENTS)
        if ctx.tiles.numel() > 0:
            composite_backward_kernel[launch.grid](
                table, flat_colors, bins.pair_gaussian, bins.tile_start, bins.tile_count,
                ctx.tiles, grad_colors.contiguous(), pixel_k[..., 0].contiguous(),
                t_final[..., 0].contiguous(), last, grad_table, grad_cols,
                *_geometry(bins, width, height), d, **launch.sizes(), **COMPILE_OPTIONS,
            )  # fmt: skip
        return input_gradients(
            grad_table, grad_cols, ctx.fixed, (means2d, conics, opacities, colors), grad_bg
        )
