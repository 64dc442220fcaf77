"""Seal a finished folder with a completion marker, written last, listing every file's sha256;
check it on load, so an unfinished folder or a changed byte is detected."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from relaygs.errors import RelayGSError

MARKER_FILE = "COMPLETE"
_CHUNK = 1 << 20


class CorruptArtifactError(RelayGSError):
    """A stored artifact or checkpoint whose bytes no longer match its recorded hashes."""


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def seal(folder: Path) -> dict[str, str]:
    """Write the completion marker listing the sha256 of every file now in `folder`; return
    those hashes by file name."""
    hashes = {
        path.name: file_sha256(path)
        for path in sorted(folder.iterdir())
        if path.is_file() and path.name != MARKER_FILE
    }
    marker = folder / MARKER_FILE
    marker.write_text(json.dumps({"sha256": hashes}, sort_keys=True, indent=1), encoding="utf-8")
    return hashes


def folder_identity(folder: Path) -> tuple[int, int] | None:
    """(device, inode) of a folder, or None when it is gone: a folder published or removed by
    another process (renamed in or out whole) changes identity, one left alone keeps it."""
    try:
        status = folder.stat()
    except (FileNotFoundError, NotADirectoryError):
        return None
    return status.st_dev, status.st_ino


def is_sealed(folder: Path) -> bool:
    """True when the folder carries a completion marker (its build finished)."""
    return (folder / MARKER_FILE).is_file()


def check_seal(folder: Path) -> None:
    """Raise CorruptArtifactError naming the folder and file unless every hash matches."""
    marker = folder / MARKER_FILE
    try:
        hashes = json.loads(marker.read_text(encoding="utf-8"))["sha256"]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as error:
        raise CorruptArtifactError(f"{marker}: unreadable completion marker ({error})") from error
    if not isinstance(hashes, dict):
        raise CorruptArtifactError(f"{marker}: completion marker holds no file hashes")
    for name, expected in sorted(hashes.items()):
        path = folder / name
        missing = CorruptArtifactError(f"{path}: file listed in {MARKER_FILE} is missing")
        if not path.is_file():
            raise missing
        try:
            actual = file_sha256(path)
        except FileNotFoundError as error:  # the folder was moved away since (gc, a rebuild)
            raise missing from error
        if actual != expected:
            raise CorruptArtifactError(
                f"{path}: sha256 mismatch (recorded {expected[:12]}…, found {actual[:12]}…)"
            )
