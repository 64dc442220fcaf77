"""The unit a stage produces: named tensors plus JSON metadata, and its on-disk form."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file

from relaygs.errors import InputError
from relaygs.pipeline.fsio import save_tensors
from relaygs.pipeline.layout import TENSORS_FILE

META_FILE = "meta.json"
NOTES = "notes"  # meta key of the artifact's notes (`Artifact.notes`)


@dataclass
class Artifact:
    """What a stage returns: safetensors tensors and JSON `meta` (its `metrics`, its `notes`)."""

    stage: str
    tensors: dict[str, torch.Tensor] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def notes(self) -> tuple[str, ...]:
        """What the stage that built it said a user should know (every run printing it, whether
        it builds the artifact or reuses it); empty when it said nothing."""
        notes = self.meta.get(NOTES, [])
        return tuple(str(note) for note in notes) if isinstance(notes, list) else ()

    def to_cpu_contiguous(self) -> Artifact:
        """This artifact with detached CPU tensors that each own their storage (as safetensors
        needs); a non-tensor, a non-finite value or inexact JSON meta is an InputError."""
        seen_storages: set[int] = set()
        tensors = {
            name: _cpu_owned(name, tensor, seen_storages) for name, tensor in self.tensors.items()
        }
        return Artifact(stage=self.stage, tensors=tensors, meta=json.loads(_meta_json(self)))


def write_artifact_files(folder: Path, artifact: Artifact) -> list[str]:
    """Write `tensors.safetensors` and `meta.json` into `folder`; return the file names."""
    cpu = artifact.to_cpu_contiguous()
    save_tensors(cpu.tensors, folder / TENSORS_FILE)
    (folder / META_FILE).write_text(_meta_json(artifact), encoding="utf-8")
    return [TENSORS_FILE, META_FILE]


def read_artifact_files(folder: Path, stage: str) -> Artifact:
    """Read an artifact written by `write_artifact_files` (no integrity check here)."""
    tensors = load_file(str(folder / TENSORS_FILE))
    meta = json.loads((folder / META_FILE).read_text(encoding="utf-8"))
    return Artifact(stage=stage, tensors=tensors, meta=meta)


def _cpu_owned(name: str, tensor: Any, seen_storages: set[int]) -> torch.Tensor:
    """`tensor` detached on the CPU, cloned unless it is contiguous and alone in its storage."""
    if not isinstance(tensor, torch.Tensor):
        raise InputError(f"artifact tensor {name!r} is a {type(tensor).__name__}, not a tensor")
    cpu = tensor.detach().to("cpu")
    if cpu.is_floating_point() and not bool(torch.isfinite(cpu).all()):
        bad = int((~torch.isfinite(cpu)).sum())
        raise InputError(
            f"artifact tensor {name!r} has {bad} non-finite value(s) of {cpu.numel()}; "
            "artifacts hold finite values only"
        )
    storage = cpu.untyped_storage()
    owns_storage = (
        cpu.is_contiguous()
        and cpu.storage_offset() == 0
        and storage.nbytes() == cpu.numel() * cpu.element_size()
        and storage.data_ptr() not in seen_storages
    )
    if not owns_storage:
        cpu = cpu.clone(memory_format=torch.contiguous_format)
    seen_storages.add(cpu.untyped_storage().data_ptr())
    return cpu


def _meta_json(artifact: Artifact) -> str:
    """Serialise meta after checking it round-trips exactly through JSON."""
    check_json_exact(artifact.meta, f"{artifact.stage} artifact meta")
    return json.dumps(artifact.meta, sort_keys=True, indent=1, allow_nan=False)


def check_json_exact(value: Any, where: str) -> None:
    """Raise InputError naming `where` unless `value` survives a JSON round trip unchanged (no
    tuples, non-string keys, NaN, infinity or numpy/torch objects)."""
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise InputError(f"{where}: key {key!r} is not a string")
            check_json_exact(item, f"{where}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            check_json_exact(item, f"{where}[{index}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"{where} is {value}; JSON has no NaN or infinity")
    elif value is not None and not isinstance(value, str | int | float | bool):
        raise InputError(
            f"{where} is a {type(value).__name__}; expected a JSON value "
            "(dict with str keys, list, str, int, float, bool or None)"
        )
