"""Durable, atomic folder publication: fsync a finished temp folder, then rename it in."""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Mapping
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import save_file

from relaygs.pipeline.layout import trash_path

PUBLISHED_DIR_MODE = 0o755
PUBLISHED_FILE_MODE = 0o644


def fsync_path(path: Path) -> None:
    """Flush a file's or folder's data and metadata to disk."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


_OS_ERROR_NUMBER = re.compile(r"\(os error (\d+)\)")
"""How safetensors' Rust writer reports an I/O failure in its message: `(os error 28)`."""


def save_tensors(tensors: Mapping[str, torch.Tensor], path: Path) -> None:
    """Write a safetensors file; an I/O failure is raised as the OSError (errno, this path) it
    is, so `resource_error` tells a full disk from a bug."""
    try:
        save_file(dict(tensors), str(path))
    except SafetensorError as error:
        found = _OS_ERROR_NUMBER.search(str(error))
        if found is None:
            raise
        number = int(found.group(1))
        raise OSError(number, os.strerror(number), str(path)) from error


def publish_text(path: Path, text: str) -> None:
    """Write `text` (UTF-8) to `path` whole or not at all (`publish_bytes`)."""
    publish_bytes(path, text.encode("utf-8"))


def publish_bytes(path: Path, data: bytes) -> None:
    """Write `path` whole or not at all (a flushed hidden file renamed in), so no reader sees
    part of one; an error names `path`, not the hidden file."""
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        partial.write_bytes(data)
        fsync_path(partial)
        os.replace(partial, path)
    except OSError as error:
        if error.errno is None:
            raise
        raise OSError(error.errno, error.strerror, str(path)) from error
    finally:
        partial.unlink(missing_ok=True)  # nothing left to remove once renamed in


def publish_dir(temp: Path, final: Path) -> None:
    """Atomically make `temp` appear as `final`, readable like any other output; an existing
    `final` is moved aside first (a rename cannot overwrite a non-empty folder), then deleted."""
    temp.chmod(PUBLISHED_DIR_MODE)  # mkdtemp makes 0700: a shared store is read by all
    for path in temp.iterdir():
        if path.is_file():
            path.chmod(PUBLISHED_FILE_MODE)
            fsync_path(path)
    fsync_path(temp)
    if final.exists():
        trash = trash_path(final.parent, final.name)
        os.replace(final, trash)
        os.replace(temp, final)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(temp, final)
    fsync_path(final.parent)


def file_identity(path: Path) -> tuple[int, int] | None:
    """(inode, mtime in ns) of `path`, None when it does not exist: whether a file was written
    (replaced) since an earlier look."""
    try:
        status = path.stat()
    except FileNotFoundError:
        return None
    return status.st_ino, status.st_mtime_ns


def remove_tree(path: Path) -> None:
    """Delete a file or folder if it exists (missing paths are fine)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
