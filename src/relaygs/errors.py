"""Exceptions that carry a one-line, user-facing message."""

from __future__ import annotations

import errno
import os


class RelayGSError(Exception):
    """Base class for errors relaygs reports to the user as a single line."""


class InputError(RelayGSError, ValueError):
    """Bad user input: a file, field or value that is not what was expected."""


class UsageError(RelayGSError):
    """Command-line options that contradict each other (exit status 2, as argparse's)."""


class DivergenceError(RelayGSError, FloatingPointError):
    """A training run produced a non-finite value; names the stage, step and tensor."""


class ResourceError(RelayGSError):
    """The machine ran out of disk or memory, or refused a write: not a bug, so one line that
    names what failed and what to do, not a traceback."""


NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
NOT_WRITABLE_ERRNOS = frozenset({errno.EROFS, errno.EACCES, errno.EPERM})
ALLOCATION_FAILURES = ("can't allocate memory", "out of memory")
"""Text of torch's failed allocations (CPU allocator; CUDA's torch.OutOfMemoryError)."""

RERUN_RUN = (
    "rerun the same command (finished stages are reused, an unfinished one resumes "
    "from its last in-stage checkpoint)"
)
RERUN_COMMAND = "rerun the command"


def resource_error(
    error: BaseException, where: str = "", rerun: str = RERUN_RUN
) -> ResourceError | None:
    """The one-line ResourceError `error` stands for (prefixed with `where`), or None when it
    is no full disk, unwritable path or failed allocation."""
    prefix = f"{where}: " if where else ""
    if isinstance(error, OSError) and error.errno in NO_SPACE_ERRNOS | NOT_WRITABLE_ERRNOS:
        return ResourceError(prefix + _disk_failure(error, rerun))
    if isinstance(error, MemoryError) or (
        isinstance(error, RuntimeError) and any(text in str(error) for text in ALLOCATION_FAILURES)
    ):
        return ResourceError(
            f"{prefix}out of memory: free memory or ask for less (a smaller scene or budget), "
            f"then {rerun}"
        )
    return None


def _disk_failure(error: OSError, rerun: str) -> str:
    """What a full or unwritable disk stopped, and what the user can do about it."""
    reason = error.strerror or os.strerror(error.errno or 0)
    if error.errno in NO_SPACE_ERRNOS:
        target = f" writing {error.filename}" if error.filename else ""
        return f"{reason}{target}: free space, then {rerun}"
    target = f" {error.filename}" if error.filename else ""
    if error.errno == errno.EROFS:
        return f"cannot write{target} ({reason}): make it writable, then {rerun}"
    # a permission refusal may be of a read (an unreadable artifact folder) or of a write
    return f"cannot access{target} ({reason}): give this user access to it, then {rerun}"


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during training, naming the stage, step and what a rerun resumes from."""


def one_line(error: BaseException) -> str:
    """An exception's message in one line, Hydra's and OmegaConf's detail lines dropped."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return " ".join(line for line in lines if not line.startswith(_DETAIL_PREFIXES))


_DETAIL_PREFIXES = ("See https://", "full_key:", "object_type=")
