"""The GPU path of the splatting core: Triton kernels projecting (`project_kernels`) and
compositing (`kernels`) forward and backward on CUDA tensors, imported on first use, behind
the contracts of the torch path (`relaygs.splat.projection`, `relaygs.splat.composite`). With
TRITON_INTERPRET=1 set before they are first used, the same kernels run on CPU tensors in
Triton's interpreter, which is how the tests check them."""

from __future__ import annotations

import functools
import importlib

import torch

DTYPES = (torch.float32, torch.float64)


@functools.cache
def available() -> bool:
    """Whether triton imports here (it ships with CUDA builds of torch; the `dev` extra too)."""
    try:
        importlib.import_module("triton")
    except ImportError:
        return False
    return True


def interpreted() -> bool:
    """Whether the kernels run in Triton's interpreter (decorated with TRITON_INTERPRET=1)."""
    from relaygs.splat.triton import kernels

    return kernels.INTERPRETED


def supports(tensor: torch.Tensor) -> bool:
    """Whether the kernels render this tensor's device and dtype: float32/float64 on CUDA,
    or on the CPU in the interpreter; call only where `available()`."""
    if tensor.dtype not in DTYPES:
        return False
    return tensor.device.type == ("cpu" if interpreted() else "cuda")


__all__ = ["available", "interpreted", "supports"]
