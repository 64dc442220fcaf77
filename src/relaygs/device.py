"""Which torch device a run may use: the CPU or a CUDA device this torch can allocate on."""

from __future__ import annotations

import torch

from relaygs.errors import InputError


def usable_device(name: str, what: str) -> torch.device:
    """`name` as a torch device, or one line naming `what` when the splatting core does not run
    there or this torch cannot allocate there (a CPU-only build, no GPU, an index past the last
    GPU). Checked before any work starts."""
    try:
        device = torch.device(name)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise InputError(f"{what}: expected 'cpu', 'cuda' or 'cuda:N', got {name!r}")
    if device.type == "cpu":
        return device
    try:
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as error:
        text = str(error).strip()
        reason = text.splitlines()[0] if text else type(error).__name__
        raise InputError(f"{what}: cannot use {name!r} here ({reason})") from None
    return device
