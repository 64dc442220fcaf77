"""Find what a sweep folder holds, all of it: a sub-folder that cannot be read is an error
(`Path.rglob` would pass over it, and the report would silently lack its jobs)."""

from __future__ import annotations

import os
from pathlib import Path

from relaygs.errors import InputError


def entries_named(root: Path, name: str) -> list[Path]:
    """Every entry called `name` below `root`, sorted; a folder that cannot be listed refused."""

    def refuse(error: OSError) -> None:
        if isinstance(error, FileNotFoundError):
            return
        raise InputError(
            f"cannot read {error.filename} ({error.strerror}): the report would leave out the "
            "jobs in it; give this user access to it"
        )

    found = []
    for folder, folders, files in os.walk(root, onerror=refuse):
        found += [Path(folder) / entry for entry in (*folders, *files) if entry == name]
    return sorted(found)
