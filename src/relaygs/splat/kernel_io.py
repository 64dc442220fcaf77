"""What the fused compositing kernels (native CPU, Triton) read and write, prepared once for
both: the packed per-Gaussian table, the flat colours, the output buffers (started from a
FixedLayer's render where given) and, in the backward, the same inputs again with the
background's terms."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from relaygs.splat.composite import FixedLayer, _pack, background_terms
from relaygs.splat.tiles import TileBins


@dataclass
class KernelInputs:
    """The packed table [C·N, columns] and flat colours [C·N, D] a kernel reads."""

    table: torch.Tensor
    colors: torch.Tensor


def kernel_inputs(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    bounds: torch.Tensor,
) -> KernelInputs:
    """The contiguous, detached table and colours of [C,N,...] projected Gaussians."""
    c, n, d = colors.shape
    table = _pack(means2d.detach(), conics.detach(), opacities.detach(), bounds).contiguous()
    return KernelInputs(table, colors.detach().reshape(c * n, d).contiguous())


def forward_buffers(
    colors: torch.Tensor, width: int, height: int, fixed: FixedLayer | None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """out [C,H,W,D], t_final [C,H,W] and last [C,H,W] (int32, -1) for a forward kernel: empty,
    or the fixed layer's render and transmittance for the tiles the kernel skips."""
    c, _, d = colors.shape
    if fixed is None:
        out = colors.new_zeros(c, height, width, d)
        t_final = colors.new_ones(c, height, width)
    else:
        out = fixed.colors.detach().to(colors.dtype).contiguous().clone()
        t_final = (1.0 - fixed.alphas.detach().to(colors.dtype))[..., 0].contiguous()
    last = torch.full((c, height, width), -1, dtype=torch.int32, device=colors.device)
    return out, t_final, last


def finish_forward(
    ctx: Any,
    out: torch.Tensor,
    t_final: torch.Tensor,
    last: torch.Tensor,
    inputs: tuple[torch.Tensor, ...],
    backgrounds: torch.Tensor | None,
    bins: TileBins,
    fixed: FixedLayer | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Add the background, save what the backward needs on `ctx`; (colors, alphas).
    `inputs` are (means2d, conics, opacities, colors, bounds)."""
    t_final = t_final[..., None]
    if backgrounds is not None:
        out = out + t_final * backgrounds[:, None, None, :]
    ctx.bins = bins
    ctx.fixed = None if fixed is None else fixed.mask
    ctx.save_for_backward(*inputs, backgrounds, t_final, last)
    return out, 1.0 - t_final


def backward_inputs(
    ctx: Any, grad_colors: torch.Tensor, grad_alphas: torch.Tensor
) -> tuple[tuple[torch.Tensor, ...], KernelInputs, torch.Tensor, torch.Tensor | None]:
    """(saved (means2d, conics, opacities, colors, bounds, t_final, last), the kernel's
    inputs, the per-pixel background factor [C,H,W], the backgrounds' gradient)."""
    means2d, conics, opacities, colors, bounds, backgrounds, t_final, last = ctx.saved_tensors
    pixel_k, grad_bg = background_terms(grad_colors, grad_alphas, t_final, backgrounds)
    saved = (means2d, conics, opacities, colors, bounds, t_final, last)
    inputs = kernel_inputs(means2d, conics, opacities, colors, bounds)
    return saved, inputs, pixel_k[..., 0].contiguous(), grad_bg


def geometry(bins: TileBins, width: int, height: int) -> tuple[int, ...]:
    """(tile size, tiles across, tiles down, width, height): the kernels' grid arguments."""
    return bins.tile_size, bins.tiles_x, bins.tiles_y, width, height
