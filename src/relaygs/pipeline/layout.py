"""The one place that spells a store's layout: `<stage>/<key>/` artifacts, `<key>.ckpt/` their
checkpoints, `.tmp-*` builds under way (or killed), `.locks/<stage>.<key>.lock` file locks."""

from __future__ import annotations

import re
import tempfile
import uuid
from pathlib import Path

from relaygs.errors import InputError

LOCKS_DIR = ".locks"
TEMP_PREFIX = ".tmp-"
TRASH_PREFIX = ".trash-"
CHECKPOINT_SUFFIX = ".ckpt"
TENSORS_FILE = "tensors.safetensors"
"""The tensors of an artifact folder and of a checkpoint folder."""
_STAGE_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
_KEY_RE = re.compile(r"[0-9a-f]{64}")


def is_key(name: str) -> bool:
    """True for a well-formed artifact key (64 lowercase hex digits)."""
    return _KEY_RE.fullmatch(name) is not None


def check_stage_and_key(stage: str, key: str) -> None:
    """Reject names that could escape the store or that no key function produces."""
    if not _STAGE_RE.fullmatch(stage):
        raise InputError(f"stage name {stage!r} must match {_STAGE_RE.pattern}")
    if not is_key(key):
        raise InputError(f"artifact key {key!r} must be 64 lowercase hex digits")


def artifact_dir(root: Path, stage: str, key: str) -> Path:
    """Folder of the finished artifact `key` of `stage`."""
    check_stage_and_key(stage, key)
    return root / stage / key


def checkpoint_dir(root: Path, stage: str, key: str) -> Path:
    """Folder of the in-stage checkpoints kept while artifact `key` is being built."""
    check_stage_and_key(stage, key)
    return root / stage / f"{key}{CHECKPOINT_SUFFIX}"


def lock_path(root: Path, stage: str, key: str) -> Path:
    """File lock that serialises building artifact `key` of `stage` across processes."""
    check_stage_and_key(stage, key)
    return root / LOCKS_DIR / f"{stage}.{key}.lock"


def make_temp_dir(parent: Path, label: str) -> Path:
    """A fresh hidden temp folder beside the final one (same filesystem, so renames are atomic)."""
    parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{label}-", dir=parent))


def trash_path(parent: Path, name: str) -> Path:
    """A fresh hidden path in `parent` to move `name` (an artifact's key) to before deleting
    it, so that no reader ever sees it half-deleted under its own name."""
    return parent / f"{TRASH_PREFIX}{name}-{uuid.uuid4().hex[:8]}"


def key_of_temp_name(name: str) -> str | None:
    """The key a temp or trash folder name was made for, or None if it is not one."""
    for prefix in (TEMP_PREFIX, TRASH_PREFIX):
        if name.startswith(prefix):
            candidate = name[len(prefix) : len(prefix) + 64]
            return candidate if is_key(candidate) else None
    return None


def key_dirs(root: Path) -> list[Path]:
    """Folders named like a key under every stage folder (finished or not)."""
    return [p for p in store_entries(root) if is_key(p.name)]


def store_entries(root: Path) -> list[Path]:
    """The folders in every stage folder (hidden ones such as `.locks` are none): the store
    writes only folders there, so a file (another tool's blob) is none of its own."""
    if not root.is_dir():
        return []
    stages = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    return [p for stage in stages for p in sorted(stage.iterdir()) if p.is_dir()]
