"""Divergence guard: stop a run at the first non-finite parameter, gradient or loss."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from relaygs.errors import DivergenceError


def check_finite(stage: str, step: int, tensors: Mapping[str, Tensor]) -> None:
    """DivergenceError naming stage, step and the first non-finite tensor or .grad; one sum per
    tensor and one host sync, each tensor checked in full only when a sum is not finite."""
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


def divergence_suspects(parameters: Mapping[str, Tensor], step: int) -> str:
    """Which parameters a divergence at `step` started from: those the previous update made
    non-finite, else the one with the largest magnitude (an update too big, not yet overflowed)."""
    non_finite = [
        name for name, tensor in parameters.items() if not bool(torch.isfinite(tensor).all())
    ]
    if non_finite:
        return (
            f"the update of step {step - 1} made parameter(s) {', '.join(non_finite)} non-finite "
            "first: lower their learning rate"
        )
    finite = [(name, tensor) for name, tensor in parameters.items() if tensor.numel()]
    if not finite:
        return "no parameter is non-finite"
    name, largest = max(
        ((name, float(tensor.detach().abs().max())) for name, tensor in finite),
        key=lambda item: item[1],
    )
    return (
        f"no parameter is non-finite; the largest is {name} (|value| up to {largest:.3g}): "
        "a learning rate too high for it?"
    )
