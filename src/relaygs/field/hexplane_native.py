"""HexPlane sampling through the native CPU kernel (relaygs.splat.native's extension): the
same features and gradients as `HexPlane`'s grid_sample path, in one pass per point."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from relaygs.splat.native.build import load


def _channel_last(planes: tuple[Tensor, ...]) -> list[Tensor]:
    return [p.detach().permute(0, 2, 3, 1).contiguous() for p in planes]


class NativeHexPlaneFeatures(torch.autograd.Function):
    """Features [N, C·levels] at grid `coords` [N,3] and `times` [N] in [-1, 1] of the planes
    spatial0, time0, spatial1, ... ([3,C,R,R], [3,C,T,R]); the times get no gradient."""

    @staticmethod
    def forward(ctx: Any, coords: Tensor, times: Tensor, *planes: Tensor) -> Tensor:
        spatial, time = _channel_last(planes[0::2]), _channel_last(planes[1::2])
        coords, times = coords.detach().contiguous(), times.detach().contiguous()
        ctx.levels = len(spatial)
        ctx.save_for_backward(coords, times, *spatial, *time)
        return load().hexplane_forward(coords, times, spatial, time)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        coords, times, *planes = ctx.saved_tensors
        spatial, time = planes[: ctx.levels], planes[ctx.levels :]
        *plane_grads, grad_coords = load().hexplane_backward(
            coords, times, spatial, time, grad.contiguous()
        )
        return grad_coords, None, *plane_grads
