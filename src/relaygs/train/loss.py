"""Image loss of every training stage: L1 + λ·D-SSIM (L1 at weight 1, as in 4D-GS's code)."""

from __future__ import annotations

import torch
from torch import Tensor

from relaygs.metrics import psnr, ssim


def photometric_loss(preds: list[Tensor], targets: list[Tensor], ssim_weight: float) -> Tensor:
    """Mean over views of L1 + ssim_weight·(1 − SSIM); images [H,W,3]. Views of one size go
    through as one batch (the same mean, a quarter of the operations at four views)."""

    def loss(pred: Tensor, target: Tensor) -> Tensor:
        l1 = (pred - target).abs().mean()
        return l1 + ssim_weight * (1.0 - ssim(pred, target)) if ssim_weight > 0.0 else l1

    if len({tuple(p.shape) for p in preds}) == 1:
        return loss(torch.stack(preds), torch.stack(targets))
    return torch.stack([loss(p, t) for p, t in zip(preds, targets, strict=True)]).mean()


@torch.no_grad()
def batch_psnr(preds: list[Tensor], targets: list[Tensor]) -> float:
    """Mean PSNR (dB) of the batch's renders, clamped to [0, 1] as at evaluation."""
    values = [psnr(p.clamp(0.0, 1.0), t) for p, t in zip(preds, targets, strict=True)]
    return float(torch.stack(values).mean())
