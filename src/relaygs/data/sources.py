"""Scene files are stat'ed before being read (a FIFO or /dev/zero would never end) and must
resolve inside the scene folder (else its content would depend on files outside)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from relaygs.errors import InputError

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def regular_file_status(path: Path, what: str = "file") -> os.stat_result:
    """`path`'s stat once it is a regular file (else InputError), before anything opens it."""
    status = path.stat()
    if not stat.S_ISREG(status.st_mode):
        kind = next((name for test, name in _KINDS if test(status.st_mode)), "not a regular file")
        raise InputError(f"{path}: is {kind}, expected a regular {what}")
    return status


def check_inside(path: Path, root: Path, what: str = "file") -> None:
    """InputError naming `path` unless it lies inside the scene folder `root` once both are
    resolved (a symlink within the folder is fine, one that leads out of it is not)."""
    resolved, inside = path.resolve(), root.resolve()
    if resolved != inside and not resolved.is_relative_to(inside):
        raise InputError(
            f"{path}: {what} resolves to {resolved}, outside the scene folder {root}; "
            "scene files must lie inside it (copy the file in, or move the scene folder)"
        )
