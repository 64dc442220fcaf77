"""Error images: the mean absolute error through a colour map, saturating at full scale."""

from __future__ import annotations

import functools

import torch
from matplotlib import colormaps

ERROR_FULL_SCALE = 0.25  # the brightest error: larger ones saturate, so small ones stay visible
COLOUR_MAP = "inferno"
LEVELS = 256


def error_image(render: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """[H,W,3] float32 in [0,1]: |render − truth| over channels, scaled by ERROR_FULL_SCALE and
    coloured with COLOUR_MAP; a pixel that is not a number shows as the largest error."""
    if render.shape != truth.shape:
        raise ValueError(f"render {list(render.shape)} and truth {list(truth.shape)} differ")
    error = (render.float() - truth.float().to(render.device)).abs().mean(dim=-1)
    error = torch.nan_to_num(error, nan=ERROR_FULL_SCALE)
    level = (error / ERROR_FULL_SCALE).clamp(0.0, 1.0) * (LEVELS - 1)
    return colour_table().to(level.device)[level.round().long()]


@functools.cache
def colour_table() -> torch.Tensor:
    """COLOUR_MAP sampled at LEVELS levels, [LEVELS,3] float32 RGB (made once; read only)."""
    samples = colormaps[COLOUR_MAP].resampled(LEVELS)(range(LEVELS))
    return torch.tensor(samples[:, :3], dtype=torch.float32)
