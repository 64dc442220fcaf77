"""Which torch device a run may use (the CPU or a CUDA device this torch can allocate on), and
how many CPU threads torch takes."""

from __future__ import annotations

import torch

from relaygs.errors import InputError


def parse_device(name: str, what: str) -> torch.device:
    """`name` as a torch device the splatting core runs on ('cpu', 'cuda', 'cuda:N'), or one
    line naming `what`. Says nothing of this machine: a job may run on another one."""
    try:
        device = torch.device(name)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise InputError(f"{what}: expected 'cpu', 'cuda' or 'cuda:N', got {name!r}")
    return device


def usable_device(name: str, what: str) -> torch.device:
    """`parse_device`, and this torch can allocate there, else one line naming `what` and why
    (a CPU-only build, no GPU, an index past the last GPU). Checked before any work starts."""
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
    """Set torch's CPU thread count to `threads` (None keeps torch's default) before any work: a
    run's `threads` and the commands' `--threads` (one thread is fastest on a busy machine)."""
    if threads is not None:
        torch.set_num_threads(threads)


def synchronize(device: torch.device) -> None:
    """Wait until `device` has finished the work queued on it, so a timer read next counts
    that work (CUDA kernels run asynchronously; on the CPU there is nothing to wait for)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
