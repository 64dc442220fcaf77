"""Colour-fitted PSNR: renders scored after each camera's best channel gain and offset (its
own colour response, docs/results.md 1b), in closed form from per-image moments."""

from __future__ import annotations

import math
from collections import defaultdict

import torch

from relaygs.metrics import MSE_FLOOR

_SUM_P, _SUM_T, _SUM_PP, _SUM_TT, _SUM_PT = range(5)


def channel_moments(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-channel float64 sums [5, C] over the pixels: Σp, Σt, Σp², Σt², Σp·t."""
    p = pred.detach().reshape(-1, pred.shape[-1]).to(torch.float64)
    t = target.detach().reshape(-1, target.shape[-1]).to(torch.float64)
    return torch.stack([p.sum(0), t.sum(0), (p * p).sum(0), (t * t).sum(0), (p * t).sum(0)])


def channel_fit(moments: torch.Tensor, count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Least-squares gain and offset per channel (gain 1 for a flat channel)."""
    mean_p, mean_t = moments[_SUM_P] / count, moments[_SUM_T] / count
    variance = moments[_SUM_PP] / count - mean_p.square()
    covariance = moments[_SUM_PT] / count - mean_p * mean_t
    flat = variance <= 1e-12
    gain = torch.where(flat, torch.ones_like(variance), covariance / variance.clamp_min(1e-12))
    return gain, mean_t - gain * mean_p


def fitted_mse(
    moments: torch.Tensor, count: int, gain: torch.Tensor, offset: torch.Tensor
) -> float:
    """MSE of gain·pred + offset against the target, from the moments (clamped at 0)."""
    sp, st, spp, stt, spt = moments
    per_channel = (
        gain.square() * spp
        + 2 * gain * offset * sp
        + count * offset.square()
        - 2 * gain * spt
        - 2 * offset * st
        + stt
    )
    return max(float(per_channel.sum()) / (count * moments.shape[1]), 0.0)


class ColourFittedPSNR:
    """Per-camera colour-fitted PSNR: `add` images, `value()` is their mean after each fit."""

    def __init__(self) -> None:
        self._images: dict[int, list[tuple[torch.Tensor, int]]] = defaultdict(list)

    def add(self, camera: int, pred: torch.Tensor, target: torch.Tensor) -> None:
        """Record one image of `camera` ([H,W,C] render and ground truth)."""
        moments = channel_moments(pred.clamp(0.0, 1.0), target)
        self._images[camera].append((moments, pred.numel() // pred.shape[-1]))

    def value(self) -> float | None:
        """Mean colour-fitted PSNR in dB over every added image; None when none was added."""
        scores = []
        for images in self._images.values():
            total = torch.stack([moments for moments, _ in images]).sum(0)
            gain, offset = channel_fit(total, sum(count for _, count in images))
            for moments, count in images:
                mse = max(fitted_mse(moments, count, gain, offset), MSE_FLOOR)
                scores.append(-10.0 * math.log10(mse))
        return sum(scores) / len(scores) if scores else None
