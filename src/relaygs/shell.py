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
    """How a printed command should start Python so that it pastes as is: `python` when that
    name finds this interpreter first, in its folder (an activated venv), else this
    interpreter's path, shell-quoted (`.venv/bin/python` run without activating the venv)."""
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
    """How a printed command should start an installed script (`tensorboard`): by its name when
    Python starts as `python` (`python_command`), else by its path beside this interpreter."""
    beside = Path(sys.executable).absolute().parent / name if sys.executable else None
    if python_command() == "python" or beside is None or not beside.exists():
        return name
    return shlex.quote(str(beside))


def path_override(key: str, folder: Path) -> str:
    """`KEY=FOLDER` (`scene.path`, `hydra.sweep.dir`) as one shell word that Hydra reads back:
    a path with characters beyond letters, digits and `_/.-` goes inside Hydra's double quotes
    (a `"` in it as `\\"`)."""
    text = str(folder)
    if re.fullmatch(r"[A-Za-z0-9_/.\-]+", text):
        return f"{key}={text}"
    # Hydra halves a run of backslashes before a quote, and a lone one escapes the quote
    escaped = re.sub(r'(\\*)"', lambda run: run[1] * 2 + '\\"', text)
    escaped = re.sub(r"(\\+)$", lambda run: run[1] * 2, escaped)
    return shlex.quote(f'{key}="{escaped}"')
