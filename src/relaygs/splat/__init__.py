"""Differentiable Gaussian splatting, gsplat-style API: a torch path (CPU and CUDA) and native
CPU kernels behind one `rasterization` entry."""

from relaygs.splat.composite import FixedLayer
from relaygs.splat.rasterize import (
    BACKENDS,
    RENDER_MODES,
    default_backend,
    native_kernels_in_use,
    rasterization,
    use_backend,
)

__all__ = [
    "BACKENDS",
    "RENDER_MODES",
    "FixedLayer",
    "default_backend",
    "native_kernels_in_use",
    "rasterization",
    "use_backend",
]
