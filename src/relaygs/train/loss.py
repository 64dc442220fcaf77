"""Image loss of every training stage: L1 + λ·D-SSIM with D-SSIM = 1 − SSIM.

L1 keeps weight 1 as in 4D-GS's code, whose default λ is 0 (L1 only); 3DGS uses
(1 − λ)·L1 + λ·D-SSIM. With `train.ssim_weight` 0.2 the 4D-GS baseline's loss is thus not
stock 4D-GS's.
"""

from __future__ import annotations

import torch
from torch import Tensor

from relaygs.metrics import psnr, ssim


def photometric_loss(preds: list[Tensor], targets: list[Tensor], ssim_weight: float) -> Tensor:
    """Mean over views of L1 + ssim_weight·(1 − SSIM); images [H,W,3]. Views of one size go
    through as one batch (the same mean, a quarter of the operations at four views)."""
    if len({tuple(p.shape) for p in preds}) == 1:
        pred, target = torch.stack(preds), torch.stack(targets)
        loss = (pred - target).abs().mean()
        if ssim_weight > 0.0:
            loss = loss + ssim_weight * (1.0 - ssim(pred, target))
        return loss
    losses = []
    for pred, target in zip(preds, targets, strict=True):
        loss = (pred - target).abs().mean()
        if ssim_weight > 0.0:
            loss = loss + ssim_weight * (1.0 - ssim(pred, target))
        losses.append(loss)
    return torch.stack(losses).mean()


@torch.no_grad()
def batch_psnr(preds: list[Tensor], targets: list[Tensor]) -> float:
    """Mean PSNR (dB) of the batch's renders, clamped to [0, 1] as at evaluation."""
    values = [psnr(p.clamp(0.0, 1.0), t) for p, t in zip(preds, targets, strict=True)]
    return float(torch.stack(values).mean())
