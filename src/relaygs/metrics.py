"""Image metrics: PSNR, fg-PSNR and SSIM of channels-last images or batches, range 1."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from relaygs.metrics_native import NativeSSIM
from relaygs.splat import native_kernels_in_use

MSE_FLOOR = 1e-10  # identical images score a finite 100 dB, not inf
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def psnr(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB per image, averaged over the batch; with `mask` ([H,W] or [B,H,W] bool) over
    masked pixels only, images with an empty mask left out (NaN when every mask is empty)."""
    pred, gt = _batched(pred, gt)
    squared = (pred - gt).square()
    if mask is None:
        mse = squared.mean(dim=(1, 2, 3))
        return _to_db(mse).mean()
    weights = _batched_mask(mask, pred).to(pred.dtype)
    count = weights.sum(dim=(1, 2)) * pred.shape[-1]
    valid = count > 0
    if not bool(valid.any()):
        return pred.new_tensor(float("nan"))
    sums = (squared * weights[..., None]).sum(dim=(1, 2, 3))
    mse = sums / torch.where(valid, count, torch.ones_like(count))
    return _to_db(mse)[valid].mean()


def fg_psnr(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """PSNR over the ground-truth foreground pixels (`mask` True), averaged per image."""
    return psnr(pred, gt, mask)


def ssim(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean SSIM, 11×11 Gaussian window (σ 1.5) zero-padded at the borders as in the 3DGS code
    (so scores compare with published ones); differentiable, native kernels on the CPU."""
    pred, gt = _batched(pred, gt)
    if native_kernels_in_use(pred) and not gt.requires_grad:
        return NativeSSIM.apply(pred, gt)
    return _ssim_torch(pred, gt)


def _ssim_torch(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """`ssim` of batches [B,H,W,C] in torch operations (the native kernel's reference)."""
    x = pred.permute(0, 3, 1, 2)
    y = gt.permute(0, 3, 1, 2)
    # the five blurred maps in one depthwise convolution (each channel is blurred alone)
    blurred = _gaussian_blur(torch.cat([x, y, x * x, y * y, x * y], dim=1))
    mu_x, mu_y, mean_xx, mean_yy, mean_xy = blurred.chunk(5, dim=1)
    var_x = mean_xx - mu_x.square()
    var_y = mean_yy - mu_y.square()
    cov = mean_xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + SSIM_C1) * (2 * cov + SSIM_C2)
    denominator = (mu_x.square() + mu_y.square() + SSIM_C1) * (
        (var_x + var_y).clamp_min(0.0) + SSIM_C2
    )
    return (numerator / denominator).mean()


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """Normalised 1D Gaussian weights [size] centred on the middle tap, in float64."""
    offsets = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    weights = torch.exp(-(offsets**2) / (2 * sigma**2))
    return weights / weights.sum()


def _gaussian_blur(images: torch.Tensor) -> torch.Tensor:
    channels = images.shape[1]
    taps = gaussian_window().to(dtype=images.dtype, device=images.device)
    horizontal = taps.view(1, 1, 1, -1).expand(channels, 1, 1, SSIM_WINDOW)
    vertical = taps.view(1, 1, -1, 1).expand(channels, 1, SSIM_WINDOW, 1)
    pad = SSIM_WINDOW // 2
    blurred = F.conv2d(images, horizontal, padding=(0, pad), groups=channels)
    return F.conv2d(blurred, vertical, padding=(pad, 0), groups=channels)


def _to_db(mse: torch.Tensor) -> torch.Tensor:
    return -10.0 / math.log(10.0) * torch.log(mse.clamp_min(MSE_FLOOR))


def _batched(pred: torch.Tensor, gt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    if pred.shape != gt.shape:
        raise ValueError(f"pred shape {list(pred.shape)} differs from gt {list(gt.shape)}")
    if pred.ndim not in (3, 4) or not pred.is_floating_point():
        raise ValueError(
            f"expected float images [H,W,C] or [B,H,W,C], got {pred.dtype} {list(pred.shape)}"
        )
    wide = torch.promote_types(pred.dtype, torch.float32)  # MSE_FLOOR is 0 in half precision
    pred, gt = pred.to(wide), gt.to(wide)
    if pred.ndim == 3:
        return pred.unsqueeze(0), gt.unsqueeze(0)
    return pred, gt


def _batched_mask(mask: torch.Tensor, images: torch.Tensor) -> torch.Tensor:
    if mask.shape not in (images.shape[1:3], images.shape[:3]):
        raise ValueError(
            f"mask shape {list(mask.shape)} does not match images {list(images.shape)}"
        )
    return mask.to(device=images.device, dtype=torch.bool).expand(images.shape[:3])
