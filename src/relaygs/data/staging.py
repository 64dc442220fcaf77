"""Hidden sibling folders that writers fill before renaming them in, so no partial output stays."""

from __future__ import annotations

import os
from pathlib import Path


def staging_prefix(out: Path) -> str:
    """Name of `out`'s staging folders up to the id of the process writing one."""
    return f".{out.name}.partial-"


def process_alive(pid: int) -> bool:
    """Whether process `pid` exists (one of another user's counts; so does an unknown answer)."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):  # no such process (or no such pid)
        return False
    except OSError:
        return True
    return True
