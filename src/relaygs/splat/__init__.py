"""Differentiable Gaussian splatting in pure torch (CPU and CUDA), gsplat-style API."""

from relaygs.splat.composite import FixedLayer
from relaygs.splat.rasterize import RENDER_MODES, rasterization

__all__ = ["RENDER_MODES", "FixedLayer", "rasterization"]
