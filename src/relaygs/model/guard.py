"""Divergence guard: stop a run at the first non-finite parameter, gradient or loss."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from relaygs.errors import DivergenceError


def check_finite(stage: str, step: int, tensors: Mapping[str, Tensor]) -> None:
    """Raise DivergenceError naming stage, step and the first non-finite tensor or its .grad.

    Fast path: one sum per tensor and a single host sync (a NaN or inf anywhere makes the sum
    non-finite). Only when a sum is not finite (or overflowed) is each tensor checked in full.
    """
    named: list[tuple[str, Tensor]] = []
    for name, tensor in tensors.items():
        named.append((name, tensor))
        if tensor.grad is not None:
            named.append((f"{name}.grad", tensor.grad))
    if not named:
        return
    device = named[0][1].device
    sums = torch.stack([t.detach().sum().to(device, torch.float32) for _, t in named])
    if bool(torch.isfinite(sums).all()):
        return
    for name, tensor in named:
        bad = int((~torch.isfinite(tensor.detach())).sum())
        if bad:
            raise DivergenceError(
                f"stage {stage!r} diverged at step {step}: tensor {name!r} has {bad} "
                f"non-finite value(s) of {tensor.numel()}"
            )
