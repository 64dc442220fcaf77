"""Locate the config tree (pipelines included) for editable and regular installs alike.

Rule (DESIGN.md "Config"): use the repository's absolute folder when the package runs from a
relaygs checkout's `src/` and the folder holds what is expected, else the copy packaged inside
`relaygs/_data/`.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

from relaygs.errors import InputError

PACKAGE_DIR = Path(__file__).resolve().parent
REPO_ROOT = PACKAGE_DIR.parents[1]
PACKAGED_DATA_DIR = PACKAGE_DIR / "_data"


def config_dir() -> Path:
    """Absolute path of the Hydra config tree (the folder holding `config.yaml`)."""
    return _locate("conf", lambda folder: (folder / "config.yaml").is_file())


def require_folder(path: Path, what: str) -> Path:
    """`path` when it is a folder; else one line, "`what`: PATH does not exist" or "... is not
    a folder"."""
    if path.is_dir():
        return path
    problem = "is not a folder" if path.exists() else "does not exist"
    raise InputError(f"{what}: {path} {problem}")


def require_creatable_folder(path: Path, what: str) -> Path:
    """`path` when it is a folder or can be made one, and files can be written there; else one
    line naming `what`. Checked before a run starts, so a bad output path fails before any
    training, not when the first file is written."""
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


def _locate(name: str, is_usable: Callable[[Path], bool]) -> Path:
    """Return the repo's `<name>/` when usable, else the packaged copy, else fail in one line."""
    in_repository = (REPO_ROOT / name,) if _in_repository() else ()
    candidates = (*in_repository, PACKAGED_DATA_DIR / name)
    for folder in candidates:
        if folder.is_dir() and is_usable(folder):
            return folder
    looked = ", ".join(str(folder) for folder in candidates)
    raise InputError(f"no usable {name}/ folder found (looked in {looked})")


def _in_repository() -> bool:
    """True when this package is the `src/relaygs` of a relaygs checkout; an installed copy's
    parent folders (`pip install --target app/lib` beside an `app/conf`) belong to others."""
    pyproject = REPO_ROOT / "pyproject.toml"
    if PACKAGE_DIR.parent != REPO_ROOT / "src" or not pyproject.is_file():
        return False
    return 'name = "relaygs"' in pyproject.read_text(encoding="utf-8", errors="replace")
