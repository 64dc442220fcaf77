"""COLMAP sparse models in binary or text form: records, readers and writers."""

from __future__ import annotations

from pathlib import Path

from relaygs.data.colmap.binary import read_binary_model, write_binary_model
from relaygs.data.colmap.model import (
    CAMERA_MODELS,
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    qvec_to_rotation,
    rotation_to_qvec,
)
from relaygs.data.colmap.text import read_text_model, write_text_model
from relaygs.errors import InputError

MODEL_FILES = ("cameras", "images", "points3D")
MODEL_SUFFIXES = (".bin", ".txt")  # binary preferred when a folder holds both


def model_suffix(folder: Path) -> str | None:
    """The suffix of the complete model in `folder` (binary preferred), or None without one."""
    for suffix in MODEL_SUFFIXES:
        if all((folder / f"{name}{suffix}").is_file() for name in MODEL_FILES):
            return suffix
    return None


def read_model(folder: str | Path) -> ColmapModel:
    """Read the model in `folder`, preferring the binary files when both forms exist."""
    folder = Path(folder)
    suffix = model_suffix(folder)
    if suffix is None:
        raise InputError(
            f"{folder}: expected a COLMAP model (cameras, images, points3D as .bin or .txt)"
        )
    return read_binary_model(folder) if suffix == ".bin" else read_text_model(folder)


def write_model(folder: Path, model: ColmapModel, *, binary: bool = True) -> None:
    """Write `model` into `folder` in binary (default) or text form."""
    if binary:
        write_binary_model(folder, model)
    else:
        write_text_model(folder, model)


__all__ = [
    "CAMERA_MODELS",
    "ColmapCamera",
    "ColmapImage",
    "ColmapModel",
    "model_suffix",
    "qvec_to_rotation",
    "read_model",
    "rotation_to_qvec",
    "write_model",
]
