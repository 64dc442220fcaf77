"""Which paths a scene may read: regular files inside the scene folder, symlinks resolved.

A FIFO would block a read forever and a device such as /dev/zero never ends, so a scene file
is stat'ed (which opens nothing) before it is read; a symlink that leads out of the scene folder
would make the scene's content depend on files its folder does not hold.
"""

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


def check_regular(path: Path, status: os.stat_result, what: str = "file") -> None:
    """InputError naming `path` unless `status` (its stat, symlinks followed) is a regular
    file's."""
    if stat.S_ISREG(status.st_mode):
        return
    kind = next((name for test, name in _KINDS if test(status.st_mode)), "not a regular file")
    raise InputError(f"{path}: is {kind}, expected a regular {what}")


def regular_file_status(path: Path, what: str = "file") -> os.stat_result:
    """`path`'s stat (symlinks followed; OSError when it cannot be had), once it is a regular
    file; anything else is an InputError naming it, before anything opens it."""
    status = path.stat()
    check_regular(path, status, what)
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
