"""Content hashes of scene files, cached per process by (path, size, mtime), and scene digests."""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from relaygs.data.imageio import image_size
from relaygs.errors import InputError


@dataclass(frozen=True)
class FileRecord:
    """What a scene needs to know about an input file: its content hash and, for images, size."""

    sha256: str
    size: int
    image_size: tuple[int, int] | None


_RECORDS: dict[tuple[str, int, int, bool], FileRecord] = {}
_RECORDS_LOCK = threading.Lock()


def file_record(path: Path, *, image: bool = False, what: str = "file") -> FileRecord:
    """Hash a file's bytes (and check an image's bytes, read its size) once per (path, size,
    mtime) per process."""
    try:
        stat = path.stat()
    except OSError as error:
        raise InputError(f"missing {what}: {path} ({error.strerror})") from None
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


def digest(payload: dict[str, Any]) -> str:
    """sha256 hex of a canonical JSON encoding of `payload`."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
