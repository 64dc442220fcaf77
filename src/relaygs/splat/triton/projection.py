"""EWA projection through the Triton kernels (`project_kernels`), same contract and numerics
as `projection.project_gaussians`: one launch forward and one backward per render, where the
torch path launches a hundred or so small kernels each way."""

from __future__ import annotations

import functools

import torch

from relaygs.splat.fused_projection import ProjectionKernels, project_fused
from relaygs.splat.triton.composite import COMPILE_OPTIONS

BLOCK = 128  # Gaussians a program projects, into every camera


@functools.cache
def _settings(
    dtype: torch.dtype, device: torch.device, near: float, far: float, eps2d: float
) -> torch.Tensor:
    """The kernels' [near, far, eps2d, smallest det kept] in the inputs' dtype (cached: one
    host-to-device copy per setting, not per render)."""
    values = [near, far, eps2d, torch.finfo(dtype).tiny ** 0.5]
    return torch.tensor(values, dtype=dtype, device=device)


def project_forward(
    means: torch.Tensor, factors: torch.Tensor, opacities: torch.Tensor,
    viewmats: torch.Tensor, ks: torch.Tensor,
    width: int, height: int, near: float, far: float, eps2d: float,
) -> list[torch.Tensor]:  # fmt: skip
    """[means2d, conics, depths, radii, visible, bounds], each [C, N, ...]."""
    from relaygs.splat.triton.project_kernels import project_forward_kernel

    cams, n = viewmats.shape[0], means.shape[0]
    int32 = {"dtype": torch.int32, "device": means.device}
    means2d, conics, depths = (
        means.new_empty(cams, n, 2),
        means.new_empty(cams, n, 3),
        means.new_empty(cams, n),
    )
    radii, bounds = torch.empty(cams, n, 2, **int32), torch.empty(cams, n, 4, **int32)
    visible = torch.empty(cams, n, dtype=torch.int8, device=means.device)
    if cams * n > 0:
        settings = _settings(means.dtype, means.device, near, far, eps2d)
        project_forward_kernel[(-(-n // BLOCK),)](
            means, factors, opacities, viewmats, ks, settings,
            means2d, conics, depths, radii, visible, bounds,
            n, cams, width, height, BLOCK=BLOCK, **COMPILE_OPTIONS,
        )  # fmt: skip
    return [means2d, conics, depths, radii, visible.view(torch.bool), bounds]


def project_backward(
    means: torch.Tensor, factors: torch.Tensor, opacities: torch.Tensor,
    viewmats: torch.Tensor, ks: torch.Tensor,
    width: int, height: int, near: float, far: float, eps2d: float,
    grad_means2d: torch.Tensor, grad_conics: torch.Tensor, grad_depths: torch.Tensor,
) -> list[torch.Tensor]:  # fmt: skip
    """[grad means [N,3], grad factors [N,3,3]], summed over the cameras."""
    from relaygs.splat.triton.project_kernels import project_backward_kernel

    cams, n = viewmats.shape[0], means.shape[0]
    grad_means, grad_factors = torch.empty_like(means), torch.empty_like(factors)
    if n > 0:
        settings = _settings(means.dtype, means.device, near, far, eps2d)
        project_backward_kernel[(-(-n // BLOCK),)](
            means, factors, opacities, viewmats, ks, settings,
            grad_means2d, grad_conics, grad_depths, grad_means, grad_factors,
            n, cams, width, height, BLOCK=BLOCK, **COMPILE_OPTIONS,
        )  # fmt: skip
    return [grad_means, grad_factors]


TRITON_PROJECTION = ProjectionKernels(project_forward, project_backward)


project_gaussians_triton = functools.partial(project_fused, TRITON_PROJECTION)
