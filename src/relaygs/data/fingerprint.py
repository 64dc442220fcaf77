"""Content hashes of scene files, cached per process by (path, size, mtime), and scene digests."""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from relaygs.data.imageio import image_size
from relaygs.data.sources import check_inside, regular_file_status
from relaygs.errors import InputError


@dataclass(frozen=True)
class FileRecord:
    """What a scene needs to know about an input file: its content hash and, for images, size."""

    sha256: str
    size: int
    image_size: tuple[int, int] | None


_RECORDS: dict[tuple[str, int, int, bool], FileRecord] = {}
_RECORDS_LOCK = threading.Lock()


def file_record(path: Path, *, root: Path, image: bool = False, what: str = "file") -> FileRecord:
    """Hash a file's bytes (and check an image's bytes, read its size) once per (path, size,
    mtime) per process; only a regular file inside the scene folder `root` is read."""
    try:
        stat = regular_file_status(path, what)
    except OSError as error:
        others = _other_extensions(path) if isinstance(error, FileNotFoundError) else []
        reason = (
            f"found {', '.join(others)} beside it: same name, other extension"
            if others
            else error.strerror
        )
        raise InputError(f"missing {what}: {path} ({reason})") from None
    check_inside(path, root, what)
    key = (str(path), stat.st_size, stat.st_mtime_ns, image)
    with _RECORDS_LOCK:
        cached = _RECORDS.get(key)
    if cached is not None:
        return cached
    try:
        data = path.read_bytes()
    except OSError as error:
        raise InputError(f"cannot read {what}: {path} ({error.strerror})") from None
    record = FileRecord(
        sha256=hashlib.sha256(data).hexdigest(),
        size=len(data),
        image_size=image_size(data, path) if image else None,
    )
    with _RECORDS_LOCK:
        _RECORDS[key] = record
    return record


def record_image(
    path: Path, size: tuple[int, int], files: dict[str, str], root: Path, what: str, origin: str
) -> None:
    """Hash a scene image into `files` by its path in `root`, refusing one whose size is not the
    `size` (width, height) that `origin` sets."""
    record = file_record(path, root=root, image=True, what=f"{what} file")
    if record.image_size != size:
        width, height = record.image_size
        raise InputError(
            f"{path}: {what} is {width}x{height}, expected {size[0]}x{size[1]} ({origin})"
        )
    files[path.relative_to(root).as_posix()] = record.sha256


def _other_extensions(path: Path) -> list[str]:
    """Files beside a missing `path` differing only in extension (a mask saved as .jpg)."""
    try:
        siblings = list(path.parent.iterdir())
    except OSError:
        return []
    return sorted(other.name for other in siblings if other.stem == path.stem and other != path)


def digest(payload: dict[str, Any]) -> str:
    """sha256 hex of a canonical JSON encoding of `payload`."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
