"""Garbage collection of an artifact store: what killed builds and finished runs leave behind,
each removed only while its key's lock is free, so no build in progress is disturbed."""

from __future__ import annotations

import os
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from filelock import FileLock, Timeout

from relaygs.errors import InputError
from relaygs.pipeline.fsio import remove_tree
from relaygs.pipeline.integrity import CorruptArtifactError, is_sealed
from relaygs.pipeline.layout import (
    CHECKPOINT_SUFFIX,
    LOCKS_DIR,
    is_key,
    key_dirs,
    key_of_temp_name,
    lock_path,
    store_entries,
    trash_path,
)
from relaygs.pipeline.manifest import read_manifest


@dataclass
class GcReport:
    """Paths removed (or that would be, in a dry run) and paths skipped as in use."""

    removed: list[Path] = field(default_factory=list)
    busy: list[Path] = field(default_factory=list)


def collect_garbage(
    root: Path,
    keep: Collection[str] | None,
    dry_run: bool,
    annotations: Collection[str] = (),
) -> GcReport:
    """Remove temp/trash folders, incomplete artifacts, stale checkpoints, free locks and, with
    `keep`, all not kept (an `annotations` entry stays while its upstreams are all kept)."""
    report = GcReport()
    kept = _kept_keys(root, keep, annotations) if keep is not None else None
    owned = [(path, _owning_key(path)) for path in store_entries(root)]
    garbage = [
        (path, key) for path, key in owned if key is not None and _is_garbage(path, key, kept)
    ]
    if garbage and not _is_store(root):
        raise InputError(
            f"gc: {root} is no artifact store (it has no {LOCKS_DIR} folder and no finished "
            f"artifact), so {garbage[0][0]} is not the store's to remove; nothing was removed"
        )
    for path, key in garbage:
        _remove_if_free(root, key, path, kept, dry_run, report)
    _remove_free_locks(root, dry_run, report)
    return report


def _is_store(root: Path) -> bool:
    """Whether `root` has a lock folder or a finished artifact (other tools, Docker's overlay2
    for one, name folders by a sha256 too)."""
    return (root / LOCKS_DIR).is_dir() or any(is_sealed(folder) for folder in key_dirs(root))


def _owning_key(path: Path) -> str | None:
    """The key a store entry belongs to, or None for entries gc does not manage."""
    if is_key(path.name):
        return path.name
    if path.name.endswith(CHECKPOINT_SUFFIX) and is_key(path.name[: -len(CHECKPOINT_SUFFIX)]):
        return path.name[: -len(CHECKPOINT_SUFFIX)]
    return key_of_temp_name(path.name)


def _is_garbage(path: Path, key: str, kept: set[str] | None) -> bool:
    """Whether an entry owned by `key` should go (see `collect_garbage`)."""
    unkept = kept is not None and key not in kept
    if is_key(path.name):
        return unkept or not is_sealed(path)
    if path.name.endswith(CHECKPOINT_SUFFIX):
        return unkept or is_sealed(path.parent / key)
    return True


def _kept_keys(root: Path, keep: Collection[str], annotations: Collection[str]) -> set[str]:
    """The kept keys, every key in their lineage (transitively), and the annotation entries
    whose upstreams are all among those."""
    parents: dict[str, list[str]] = {}
    annotation_keys = []
    for folder in key_dirs(root):
        if is_sealed(folder):
            try:
                parents[folder.name] = [entry.key for entry in read_manifest(folder).lineage]
            except CorruptArtifactError:
                parents[folder.name] = []
            if folder.parent.name in annotations:
                annotation_keys.append(folder.name)
    unknown = sorted(set(keep) - set(parents))
    if unknown:
        raise InputError(
            f"gc: no finished artifact with key {unknown[0]} in {root}; nothing was removed"
        )
    kept: set[str] = set()
    pending = list(keep)
    while pending:
        key = pending.pop()
        if key not in kept:
            kept.add(key)
            pending.extend(parents.get(key, []))
    described = [key for key in annotation_keys if parents[key] and set(parents[key]) <= kept]
    return kept | set(described)


@contextmanager
def lock_if_free(lock_file: Path) -> Iterator[bool]:
    """Hold `lock_file` for the block if nobody else does; yields whether it is held."""
    lock = FileLock(str(lock_file))
    try:
        lock.acquire(timeout=0)
    except Timeout:
        yield False
        return
    try:
        yield True
    finally:
        lock.release()


def _remove_if_free(
    root: Path, key: str, path: Path, kept: set[str] | None, dry_run: bool, report: GcReport
) -> None:
    """Remove `path` under its key's lock, or note it as busy; whether it is garbage is asked
    again under the lock (a build or another gc may have acted meanwhile)."""
    lock_file = lock_path(root, path.parent.name, key)
    lock_file.parent.mkdir(parents=True, exist_ok=True)
    with lock_if_free(lock_file) as free:
        if not free:
            report.busy.append(path)
            return
        if not path.is_dir() or not _is_garbage(path, key, kept):
            return
        report.removed.append(path)
        if dry_run:
            return
        if key_of_temp_name(path.name) is None:  # renamed to trash first: a kill part-way
            trash = trash_path(path.parent, key)  # leaves no half-deleted entry under its name
            os.replace(path, trash)
            path = trash
        remove_tree(path)


def _remove_free_locks(root: Path, dry_run: bool, report: GcReport) -> None:
    """Delete lock files nobody holds (unlinked while held: a waiter that opened one before
    flocks a file no longer at its path, which filelock >= 3.20.4 sees and tries again)."""
    locks = root / LOCKS_DIR
    if not locks.is_dir():
        return
    for lock_file in sorted(locks.glob("*.lock")):
        with lock_if_free(lock_file) as free:
            if not free:
                report.busy.append(lock_file)
                continue
            report.removed.append(lock_file)
            if not dry_run:
                lock_file.unlink(missing_ok=True)
