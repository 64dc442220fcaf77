"""Which torch device a run may use (the CPU or a CUDA device this torch can allocate on), and
how many CPU threads torch takes."""

from __future__ import annotations

import torch

from relaygs.errors import InputError


def parse_device(name: str, what: str) -> torch.device:
    """`name` as a 'cpu', 'cuda' or 'cuda:N' device, or one line naming `what` (not checked
    on this machine: a job may run on another)."""
    try:
        device = torch.device(name)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise InputError(f"{what}: expected 'cpu', 'cuda' or 'cuda:N', got {name!r}")
    return device


def usable_device(name: str, what: str) -> torch.device:
    """`parse_device`, where this torch can allocate, else one line naming `what` and why."""
    device = parse_device(name, what)
    if device.type == "cpu":
        return device
    try:
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as error:
        text = str(error).strip()
        reason = text.splitlines()[0] if text else type(error).__name__
        raise InputError(f"{what}: cannot use {name!r} here ({reason})") from None
    return device


def set_threads(threads: int | None) -> None:
    """Set torch's CPU thread count to `threads` (None keeps torch's default)."""
    if threads is not None:
        torch.set_num_threads(threads)


def synchronize(device: torch.device) -> None:
    """Wait until `device` has finished its queued work, so a timer read next counts it."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
