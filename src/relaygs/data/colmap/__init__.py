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


def is_model_folder(folder: Path) -> bool:
    """True when `folder` holds a complete binary or text COLMAP model."""
    return any(
        all((folder / f"{name}{ext}").is_file() for name in MODEL_FILES) for ext in (".bin", ".txt")
    )


def read_model(folder: Path) -> ColmapModel:
    """Read the model in `folder`, preferring the binary files when both forms exist."""
    if all((folder / f"{name}.bin").is_file() for name in MODEL_FILES):
        return read_binary_model(folder)
    if all((folder / f"{name}.txt").is_file() for name in MODEL_FILES):
        return read_text_model(folder)
    raise InputError(
        f"{folder}: expected a COLMAP model (cameras, images, points3D as .bin or .txt)"
    )


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
    "is_model_folder",
    "qvec_to_rotation",
    "read_model",
    "rotation_to_qvec",
    "write_model",
]
