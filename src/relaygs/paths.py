"""Locate the config tree: a relaygs checkout's own folder, else the copy packaged inside
`relaygs/_data/` (DESIGN.md "Config"); check folders given for output."""

from __future__ import annotations

import tempfile
from pathlib import Path

from relaygs.errors import InputError

PACKAGE_DIR = Path(__file__).resolve().parent
REPO_ROOT = PACKAGE_DIR.parents[1]
PACKAGED_DATA_DIR = PACKAGE_DIR / "_data"


def config_dir() -> Path:
    """The repo's `conf/` when it holds `config.yaml`, else the packaged copy; else one line."""
    candidates = (*((REPO_ROOT / "conf",) if _in_repository() else ()), PACKAGED_DATA_DIR / "conf")
    for folder in candidates:
        if (folder / "config.yaml").is_file():
            return folder
    looked = ", ".join(str(folder) for folder in candidates)
    raise InputError(f"no usable conf/ folder found (looked in {looked})")


def require_folder(path: Path, what: str) -> Path:
    """`path` when it is a folder; else one line naming `what`."""
    if path.is_dir():
        return path
    problem = "is not a folder" if path.exists() else "does not exist"
    raise InputError(f"{what}: {path} {problem}")


def require_creatable_folder(path: Path, what: str) -> Path:
    """`path` when it is (or can be made) a folder files can be written in; else one line
    naming `what`, so a bad output path fails before any training."""
    if path.exists():
        require_folder(path, what)
        probe_in = path
    else:
        probe_in = path.parent
        while not probe_in.exists():
            probe_in = probe_in.parent
        if not probe_in.is_dir():
            raise InputError(f"{what}: cannot create {path}: {probe_in} is not a folder")
    try:  # permissions alone miss read-only mounts, /proc and root's overrides
        with tempfile.TemporaryFile(dir=probe_in, prefix=".relaygs-write-test-"):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise InputError(f"{what}: cannot write in {probe_in} ({reason})") from None
    return path


def _in_repository() -> bool:
    """True when this package is the `src/relaygs` of a relaygs checkout; an installed copy's
    parent folders (`pip install --target app/lib` beside an `app/conf`) belong to others."""
    pyproject = REPO_ROOT / "pyproject.toml"
    if PACKAGE_DIR.parent != REPO_ROOT / "src" or not pyproject.is_file():
        return False
    return 'name = "relaygs"' in pyproject.read_text(encoding="utf-8", errors="replace")
