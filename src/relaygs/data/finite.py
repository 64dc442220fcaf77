"""Whether input numbers survive the cast to float32, the precision every stage trains in."""

from __future__ import annotations

import numpy as np

FLOAT32_MAX = float(np.finfo(np.float32).max)
FINITE = "NaN, inf, or beyond ±3.4e38"  # what `finite_in_float32` refuses, for messages


def finite_in_float32(values: np.ndarray) -> np.ndarray:
    """Elementwise: finite and within float32's range (a larger float64 would turn into inf
    when the scene is cast, with no more than a numpy warning)."""
    return np.abs(np.asarray(values, dtype=np.float64)) <= FLOAT32_MAX
