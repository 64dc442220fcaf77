"""Shell words of the commands the tools print for a user to paste: how to start Python or an
installed script, and a path as a Hydra override."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import sys
from pathlib import Path


def python_command() -> str:
    """How a printed command starts Python: `python` when that name finds this interpreter
    (an activated venv), else its shell-quoted path."""
    if not sys.executable:
        return "python"
    found = shutil.which("python")
    here = Path(sys.executable).absolute()
    if (
        found is not None
        and Path(found).absolute().parent == here.parent
        and os.path.samefile(found, here)
    ):
        return "python"
    return shlex.quote(str(here))


def script_command(name: str) -> str:
    """How a printed command starts an installed script: by name, or by its path beside this
    interpreter when Python is not started as `python`."""
    beside = Path(sys.executable).absolute().parent / name if sys.executable else None
    if python_command() == "python" or beside is None or not beside.exists():
        return name
    return shlex.quote(str(beside))


def path_override(key: str, folder: Path) -> str:
    """`KEY=FOLDER` as one shell word that Hydra reads back (an unusual path in its quotes)."""
    text = str(folder)
    if re.fullmatch(r"[A-Za-z0-9_/.\-]+", text):
        return f"{key}={text}"
    # Hydra halves a run of backslashes before a quote, and a lone one escapes the quote
    escaped = re.sub(r'(\\*)"', lambda run: run[1] * 2 + '\\"', text)
    escaped = re.sub(r"(\\+)$", lambda run: run[1] * 2, escaped)
    return shlex.quote(f'{key}="{escaped}"')
