"""EWA projection through the native CPU kernels, same contract and numerics as
`projection.project_gaussians` (`fused_projection.project_fused` with the native kernels):
one pass over the Gaussians forward, one backward that recomputes each (camera, Gaussian)
pair and sums over cameras per Gaussian."""

from __future__ import annotations

import functools

import torch

from relaygs.splat.fused_projection import ProjectionKernels, project_fused
from relaygs.splat.native.build import load


def _forward(*args: object) -> list[torch.Tensor]:
    return load().project_forward(*args)  # built on first use


def _backward(*args: object) -> list[torch.Tensor]:
    return load().project_backward(*args)


NATIVE_PROJECTION = ProjectionKernels(_forward, _backward)
project_gaussians_native = functools.partial(project_fused, NATIVE_PROJECTION)
