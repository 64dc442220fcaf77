"""Colour-fitted PSNR: a camera's renders scored after its best per-channel gain and offset."""

from __future__ import annotations

import pytest
import torch

from relaygs.colour_fit import ColourFittedPSNR, channel_fit, channel_moments
from relaygs.metrics import psnr


def _images(seed: int, count: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed)
    pairs = []
    for _ in range(count):
        pred = torch.rand(6, 5, 3, generator=generator)
        pairs.append((pred, (pred * 0.7 + 0.1 + 0.05 * torch.rand(6, 5, 3, generator=generator))))
    return pairs


def test_closed_form_equals_fitting_the_images_and_scoring_them():
    cameras = {3: _images(0, 4), 8: _images(1, 2)}
    accumulator = ColourFittedPSNR()
    explicit = []
    for camera, pairs in cameras.items():
        for pred, target in pairs:
            accumulator.add(camera, pred, target)
        preds = torch.stack([p for p, _ in pairs]).double()
        targets = torch.stack([t for _, t in pairs]).double()
        gain, offset = channel_fit(channel_moments(preds, targets), preds[..., 0].numel())
        explicit += [float(psnr(p * gain + offset, t)) for p, t in zip(preds, targets, strict=True)]
    assert accumulator.value() == pytest.approx(sum(explicit) / len(explicit), abs=1e-6)
    # a camera's gain and offset cost nothing, content errors do
    pairs = _images(2, 3)
    exact, wrong = ColourFittedPSNR(), ColourFittedPSNR()
    for pred, _ in pairs:
        exact.add(0, pred, pred * torch.tensor([0.9, 1.1, 1.0]) + 0.03)
        wrong.add(0, pred, pred.flip(0))  # other content: no gain or offset fits it
    assert exact.value() == pytest.approx(100.0)  # the MSE floor of `psnr`
    assert wrong.value() < 20.0
    assert ColourFittedPSNR().value() is None
    # flat renders keep gain one and stay finite
    accumulator = ColourFittedPSNR()
    accumulator.add(0, torch.full((4, 4, 3), 0.5), torch.rand(4, 4, 3))
    assert 0.0 < accumulator.value() < 100.0
