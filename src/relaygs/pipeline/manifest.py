"""manifest.json: the human-readable record of how an artifact was made and what it holds."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from relaygs.pipeline.integrity import CorruptArtifactError, file_sha256

MANIFEST_FILE = "manifest.json"
MANIFEST_FORMAT = 1
BUILT_BY = "built_by"
"""The provenance entry naming the job that built the artifact (run folder `#` digest), so a
sweep resumed in place counts what its own jobs built before it was interrupted."""
_FIELD_TYPES: dict[str, type | tuple[type, ...]] = {
    "key": str,
    "stage": str,
    "config": dict,
    "lineage": list,
    "metrics": dict,
    "wall_seconds": (int, float),
    "created": str,
    "package_version": str,
    "files": dict,
    "provenance": dict,
    "format": int,
}
"""The JSON type of each manifest field (a missing one without a default is refused when the
Manifest is made)."""


def built_by(provenance: Mapping[str, Any]) -> str | None:
    """The job a manifest's provenance names as the artifact's builder (`BUILT_BY`), if any."""
    builder = provenance.get(BUILT_BY)
    return builder if isinstance(builder, str) else None


@dataclass(frozen=True)
class LineageEntry:
    """One direct upstream artifact: the pipeline node it came from, its stage and key."""

    node: str
    stage: str
    key: str


@dataclass(frozen=True)
class Manifest:
    """Everything recorded about one stored artifact (see docs/artifacts.md)."""

    key: str
    stage: str
    config: dict[str, Any]
    lineage: list[LineageEntry]
    metrics: dict[str, Any]
    wall_seconds: float
    created: str
    package_version: str
    files: dict[str, dict[str, Any]]
    provenance: dict[str, Any] = field(default_factory=dict)
    format: int = MANIFEST_FORMAT

    @property
    def size_mb(self) -> float:
        """The data files' size on disk in MB (10^6 bytes): the storage every table reports."""
        return sum(int(entry["bytes"]) for entry in self.files.values()) / 1e6


def describe_files(folder: Path, names: list[str]) -> dict[str, dict[str, Any]]:
    """Per-file sha256 and size for the manifest."""
    return {
        name: {"sha256": file_sha256(folder / name), "bytes": (folder / name).stat().st_size}
        for name in names
    }


def write_manifest(folder: Path, manifest: Manifest) -> None:
    """Write `manifest.json` into `folder`."""
    text = json.dumps(asdict(manifest), sort_keys=True, indent=1)
    (folder / MANIFEST_FILE).write_text(text, encoding="utf-8")


def read_manifest(folder: Path) -> Manifest:
    """Parse `manifest.json` of an artifact folder; CorruptArtifactError if it is unreadable."""
    path = folder / MANIFEST_FILE
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
        _check_types(raw)
        lineage = [LineageEntry(**entry) for entry in raw.pop("lineage")]
        return Manifest(lineage=lineage, **raw)
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as error:
        raise CorruptArtifactError(f"{path}: unreadable manifest ({error})") from error


def _check_types(raw: Any) -> None:
    """Raise TypeError naming the first field, file entry or lineage entry of a parsed
    manifest that is not of the type written, so that no reader trips over an edited one."""
    if not isinstance(raw, dict):
        raise TypeError(f"expected a JSON object, got {type(raw).__name__}")
    for name, expected in _FIELD_TYPES.items():
        value = raw.get(name)
        if name in raw and (isinstance(value, bool) or not isinstance(value, expected)):
            raise TypeError(f"field {name!r} has the wrong type: {value!r}")
    for name, entry in raw.get("files", {}).items():
        if not isinstance(entry, dict) or not isinstance(entry.get("bytes"), int):
            raise TypeError(f"files entry {name!r} has no byte count: {entry!r}")
    for entry in raw.get("lineage", []):
        if not isinstance(entry, dict) or not all(isinstance(v, str) for v in entry.values()):
            raise TypeError(f"lineage entry is not an object of strings: {entry!r}")
