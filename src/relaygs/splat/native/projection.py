"""EWA projection through the native CPU kernel, same contract and numerics as
`projection.project_gaussians`: one pass over the Gaussians forward, one backward that
recomputes each (camera, Gaussian) pair and sums over cameras per Gaussian."""

from __future__ import annotations

from typing import Any

import torch

from relaygs.splat.native.build import load
from relaygs.splat.projection import Projection, project_gaussians


class NativeProjectGaussians(torch.autograd.Function):
    """(means2d, conics, depths, radii, visible, bounds) of `project_gaussians`."""

    @staticmethod
    def forward(
        ctx: Any,
        means: torch.Tensor,
        factors: torch.Tensor,
        opacities: torch.Tensor,
        viewmats: torch.Tensor,
        Ks: torch.Tensor,
        settings: tuple[int, int, float, float, float],
    ) -> tuple[torch.Tensor, ...]:
        inputs = [
            t.detach().to(means.dtype).contiguous()
            for t in (means, factors, opacities, viewmats, Ks)
        ]
        outputs = load().project_forward(*inputs, *settings)
        ctx.settings = settings
        ctx.save_for_backward(*inputs)
        ctx.mark_non_differentiable(*outputs[3:])
        return tuple(outputs)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(
        ctx: Any, grad_means2d: torch.Tensor, grad_conics: torch.Tensor, grad_depths: torch.Tensor,
        *_: Any,
    ) -> tuple[torch.Tensor | None, ...]:  # fmt: skip
        means, factors, opacities, viewmats, Ks = ctx.saved_tensors
        grads = [
            torch.zeros(shape, dtype=means.dtype) if g is None else g.contiguous()
            for g, shape in (
                (grad_means2d, (*viewmats.shape[:1], means.shape[0], 2)),
                (grad_conics, (*viewmats.shape[:1], means.shape[0], 3)),
                (grad_depths, (*viewmats.shape[:1], means.shape[0])),
            )
        ]
        grad_means, grad_factors = load().project_backward(
            means, factors, opacities, viewmats, Ks, *ctx.settings, *grads
        )
        return grad_means, grad_factors, None, None, None, None


def project_gaussians_native(
    means: torch.Tensor,
    factors: torch.Tensor,
    opacities: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
) -> Projection:
    """`project_gaussians` by the native kernel; cameras that need gradients (which the
    kernel does not give) take the torch path."""
    if viewmats.requires_grad or Ks.requires_grad:
        return project_gaussians(
            means, factors, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d
        )
    settings = (width, height, float(near_plane), float(far_plane), float(eps2d))
    outputs = NativeProjectGaussians.apply(
        means, factors, opacities.detach(), viewmats, Ks, settings
    )
    return Projection(*outputs)
