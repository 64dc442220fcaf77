"""HexPlane sampling and smoothness through the native CPU kernels (relaygs.splat.native's
extension): the same values and gradients as `HexPlane`'s torch path, in one pass."""

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


class NativeSecondDifferenceEnergy(torch.autograd.Function):
    """`second_difference_energy` of planes [P,C,H,W] along H (`rows`) and/or W (`columns`):
    the kernel returns the gradient with the energy, so the backward only scales it."""

    @staticmethod
    def forward(ctx: Any, planes: Tensor, rows: bool, columns: bool) -> Tensor:
        energy, grad = load().second_difference(planes.detach(), rows, columns)
        ctx.save_for_backward(grad)
        return energy

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        (planes_grad,) = ctx.saved_tensors
        return planes_grad * grad, None, None
