"""SSIM through the native CPU kernel: value and gradient of `relaygs.metrics.ssim`."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from relaygs.splat.native.build import load


class NativeSSIM(torch.autograd.Function):
    """Mean SSIM of channel-last batches `pred`, `gt` [B,H,W,C]; `gt` gets no gradient."""

    @staticmethod
    def forward(ctx: Any, pred: Tensor, gt: Tensor) -> Tensor:
        pred, gt = pred.detach().contiguous(), gt.detach().contiguous()
        mean, blurred = load().ssim_forward(pred, gt)
        ctx.save_for_backward(pred, gt, blurred)
        return mean

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None]:
        pred, gt, blurred = ctx.saved_tensors
        return load().ssim_backward(pred, gt, blurred, grad), None
