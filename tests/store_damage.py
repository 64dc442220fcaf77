"""Damage that a stored artifact's hashes do not catch: bytes broken before they were sealed."""

from __future__ import annotations

import json
from pathlib import Path

from relaygs.pipeline.integrity import file_sha256, seal


def damage_dtype_and_rehash(folder: Path) -> None:
    """Turn the first F32 tensor of `folder`'s safetensors into F64 (its bytes then no longer
    fit its shape), and record the new bytes' hashes in the manifest and the marker."""
    tensors = folder / "tensors.safetensors"
    tensors.write_bytes(tensors.read_bytes().replace(b'"F32"', b'"F64"', 1))
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"]["tensors.safetensors"]["sha256"] = file_sha256(tensors)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    seal(folder)
