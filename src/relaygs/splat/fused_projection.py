"""The fused projection kernels' autograd, shared by the native CPU and the Triton kernels:
the contract of `projection.project_gaussians`, one kernel pass forward and one backward that
recomputes each (camera, Gaussian) pair and sums its gradient over the cameras."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from relaygs.splat.projection import Projection, project_gaussians


@dataclass(frozen=True)
class ProjectionKernels:
    """A backend's two kernels: forward(means, factors, opacities, viewmats, Ks, width,
    height, near, far, eps2d) → [means2d, conics, depths, radii, visible, bounds] and
    backward(the same inputs, grad means2d, grad conics, grad depths) → [grad means,
    grad factors]."""

    forward: Callable[..., list[torch.Tensor]]
    backward: Callable[..., list[torch.Tensor]]


class FusedProjectGaussians(torch.autograd.Function):
    """(means2d, conics, depths, radii, visible, bounds) of `project_gaussians`."""

    @staticmethod
    def forward(
        ctx: Any,
        kernels: ProjectionKernels,
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
        outputs = kernels.forward(*inputs, *settings)
        ctx.kernels, ctx.settings = kernels, settings
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
        cams, n = viewmats.shape[0], means.shape[0]
        grads = [
            means.new_zeros(shape) if g is None else g.contiguous()
            for g, shape in (
                (grad_means2d, (cams, n, 2)),
                (grad_conics, (cams, n, 3)),
                (grad_depths, (cams, n)),
            )
        ]
        grad_means, grad_factors = ctx.kernels.backward(
            means, factors, opacities, viewmats, Ks, *ctx.settings, *grads
        )
        return None, grad_means, grad_factors, None, None, None, None


def project_fused(
    kernels: ProjectionKernels,
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
    """`project_gaussians` by `kernels`; cameras that need gradients (which the kernels do
    not give) take the torch path."""
    if viewmats.requires_grad or Ks.requires_grad:
        return project_gaussians(
            means, factors, opacities, viewmats, Ks, width, height, near_plane, far_plane, eps2d
        )
    settings = (width, height, float(near_plane), float(far_plane), float(eps2d))
    outputs = FusedProjectGaussians.apply(
        kernels, means, factors, opacities.detach(), viewmats, Ks, settings
    )
    return Projection(*outputs)
