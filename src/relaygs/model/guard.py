"""Divergence guard: stop a run at the first non-finite parameter, gradient or loss."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from relaygs.errors import DivergenceError


def check_finite(stage: str, step: int, tensors: Mapping[str, Tensor]) -> None:
    """Raise DivergenceError naming stage, step and the first non-finite tensor or its .grad.

    One fused isfinite().all() per tensor and a single host sync for the whole dict.
    """
    named: list[tuple[str, Tensor]] = []
    for name, tensor in tensors.items():
        named.append((name, tensor))
        if tensor.grad is not None:
            named.append((f"{name}.grad", tensor.grad))
    if not named:
        return
    device = named[0][1].device
    flags = torch.stack([torch.isfinite(t.detach()).all().to(device) for _, t in named])
    if bool(flags.all()):
        return
    first_bad = int((~flags).nonzero()[0, 0])
    name, tensor = named[first_bad]
    bad = int((~torch.isfinite(tensor.detach())).sum())
    raise DivergenceError(
        f"stage {stage!r} diverged at step {step}: tensor {name!r} has {bad} non-finite "
        f"value(s) of {tensor.numel()}"
    )
