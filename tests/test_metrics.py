"""PSNR, foreground PSNR and SSIM against values derived by hand or by a direct formula, with
SSIM on both paths (`splat_backend`: torch operations, or the native kernel on CPU)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from numpy.lib.stride_tricks import sliding_window_view

from relaygs.metrics import _ssim_torch, fg_psnr, psnr, ssim
from relaygs.metrics_native import NativeSSIM

pytestmark = pytest.mark.usefixtures("splat_backend")

# SSIM stabilisers for data range 1 (Wang et al. 2004), written out rather than imported so
# that the tests check the module's constants instead of reusing them.
C1 = 0.01**2
C2 = 0.03**2


def _gaussian_taps() -> np.ndarray:
    offsets = np.arange(11) - 5.0
    taps = np.exp(-(offsets**2) / (2 * 1.5**2))
    return taps / taps.sum()


def _direct_ssim(x: np.ndarray, y: np.ndarray) -> float:
    """SSIM by explicit weighted sums over each pixel's zero-padded 11×11 neighbourhood."""
    weights = np.outer(_gaussian_taps(), _gaussian_taps())
    pad = ((5, 5), (5, 5), (0, 0))
    wx = sliding_window_view(np.pad(x, pad), (11, 11), axis=(0, 1))  # [H, W, C, 11, 11]
    wy = sliding_window_view(np.pad(y, pad), (11, 11), axis=(0, 1))

    def mean(windows: np.ndarray) -> np.ndarray:
        return (weights * windows).sum(axis=(-2, -1))

    mx, my = mean(wx), mean(wy)
    vx, vy, cxy = mean(wx * wx) - mx * mx, mean(wy * wy) - my * my, mean(wx * wy) - mx * my
    values = (2 * mx * my + C1) * (2 * cxy + C2) / ((mx * mx + my * my + C1) * (vx + vy + C2))
    return float(values.mean())


def test_psnr_of_a_known_error_is_exact_and_other_shapes_are_refused():
    gt = torch.rand(8, 9, 3) * 0.6 + 0.2
    assert psnr(gt + 0.1, gt).item() == pytest.approx(20.0, abs=1e-4)
    assert psnr(gt - 0.01, gt).item() == pytest.approx(40.0, abs=1e-3)
    batch = torch.stack([gt + 0.1, gt - 0.01])  # averaged per image, not per pixel
    assert psnr(batch, torch.stack([gt, gt])).item() == pytest.approx(30.0, abs=1e-3)
    with pytest.raises(ValueError, match="differs"):
        psnr(torch.rand(4, 4, 3), torch.rand(4, 5, 3))
    with pytest.raises(ValueError, match="mask shape"):
        fg_psnr(torch.rand(4, 4, 3), torch.rand(4, 4, 3), torch.ones(3, 3, dtype=torch.bool))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float16, torch.bfloat16])
def test_psnr_of_identical_images_is_capped_at_100_db(dtype):
    image = torch.rand(4, 5, 3).to(dtype)
    value = psnr(image, image)
    assert math.isfinite(value.item())
    assert value.item() == pytest.approx(100.0)


def test_masked_psnr_counts_only_masked_pixels_and_leaves_out_empty_masks():
    gt = torch.full((6, 6, 3), 0.5)
    pred = gt.clone()
    pred[:3] += 0.1
    pred[3:] += 0.3
    mask = torch.zeros(6, 6, dtype=torch.bool)
    mask[:3] = True
    assert fg_psnr(pred, gt, mask).item() == pytest.approx(20.0, abs=1e-4)
    assert psnr(pred, gt, ~mask).item() == pytest.approx(-10 * math.log10(0.09), abs=1e-4)
    gt = torch.full((2, 4, 4, 3), 0.5)
    pred = gt + 0.1
    pred[1] += 0.2
    mask = torch.zeros(2, 4, 4, dtype=torch.bool)
    mask[0] = True
    assert fg_psnr(pred, gt, mask).item() == pytest.approx(20.0, abs=1e-4)
    assert math.isnan(fg_psnr(pred, gt, torch.zeros_like(mask)).item())


def _flat(value: float, *shape: int) -> torch.Tensor:
    return torch.full(shape, value, dtype=torch.float64)


def _noisy_pair() -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(3)
    x = torch.rand(9, 13, 2, generator=generator, dtype=torch.float64)
    return x, (x + 0.2 * torch.rand(9, 13, 2, generator=generator, dtype=torch.float64)).clamp(0, 1)


@pytest.mark.parametrize(
    "pair",
    [
        _noisy_pair(),
        # flat images: only the zero-padded borders move SSIM off (2ab + C1) / (a² + b² + C1)
        (_flat(0.3, 14, 17, 3), _flat(0.7, 14, 17, 3)),
        (_flat(0.2, 1, 1, 1), _flat(0.8, 1, 1, 1)),  # a 1×1 image: the window's centre tap alone
    ],
)
def test_ssim_matches_a_direct_window_computation(pair):
    x, y = pair
    assert ssim(x, y).item() == pytest.approx(_direct_ssim(x.numpy(), y.numpy()), abs=1e-9)


def test_dssim_loss_is_differentiable_descends_and_stays_finite_on_flat_images():
    target = torch.rand(16, 16, 3)
    pred = torch.rand(16, 16, 3, requires_grad=True)
    loss = 1 - ssim(pred, target)
    loss.backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all()
    with torch.no_grad():
        stepped = pred - 0.5 * pred.grad / pred.grad.abs().max()
    assert (1 - ssim(stepped, target)).item() < loss.item()
    flat = torch.full((12, 12, 3), 0.5, requires_grad=True)  # zero variance: the clamp at 0
    (1 - ssim(flat, torch.full((12, 12, 3), 0.5))).backward()
    assert torch.isfinite(flat.grad).all()
    # a batch's SSIM is the mean of its images'
    images = torch.rand(3, 10, 12, 3)
    targets = torch.rand(3, 10, 12, 3)
    single = torch.stack([ssim(images[i], targets[i]) for i in range(3)]).mean()
    assert ssim(images, targets).item() == pytest.approx(single.item(), abs=1e-6)
    assert ssim(images, images).item() == pytest.approx(1.0, abs=1e-6)  # identical images


@pytest.mark.parametrize("sizes", [[(9, 12)] * 4, [(9, 12), (7, 12), (9, 12)]])
def test_the_photometric_loss_is_the_mean_of_each_views_loss(sizes):
    # views of one size go through as one batch, mixed sizes one by one: the same value
    from relaygs.train.loss import photometric_loss

    generator = torch.Generator().manual_seed(5)
    preds = [torch.rand(h, w, 3, generator=generator, dtype=torch.float64) for h, w in sizes]
    targets = [torch.rand(h, w, 3, generator=generator, dtype=torch.float64) for h, w in sizes]
    pairs = zip(preds, targets, strict=True)
    expected = torch.stack([(p - t).abs().mean() + 0.2 * (1.0 - ssim(p, t)) for p, t in pairs])
    expected = expected.mean()
    torch.testing.assert_close(photometric_loss(preds, targets, 0.2), expected)


def test_the_native_ssim_equals_the_torch_ssim_and_its_gradient(splat_backend):
    if splat_backend != "native":
        pytest.skip("compares the native kernel with the torch path")
    generator = torch.Generator().manual_seed(2)
    x = torch.rand(3, 17, 23, 3, generator=generator, dtype=torch.float64)
    y = (x + 0.2 * torch.randn(x.shape, generator=generator, dtype=torch.float64)).clamp(0, 1)
    x[0, :6], y[0, :6] = 0.5, 0.5  # a flat patch: zero variance, the clamp at 0
    grads = []
    for fn in (NativeSSIM.apply, _ssim_torch):
        pred = x.clone().requires_grad_()
        value = fn(pred, y)
        value.backward()
        grads.append((value.detach(), pred.grad))
    (value, grad), (expected, expected_grad) = grads
    torch.testing.assert_close(value, expected, rtol=0, atol=1e-14)
    torch.testing.assert_close(grad, expected_grad, rtol=1e-10, atol=1e-16)
    small = x[:1, :7, :8].clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda p: NativeSSIM.apply(p, y[:1, :7, :8]), (small,))
