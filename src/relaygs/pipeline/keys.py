"""Content-addressed artifact keys: sha256 of a canonical JSON of everything that shapes a result,
never of where things go or how a run is watched (`is_non_key_name`)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any

from relaygs.errors import InputError

NON_KEY_NAMES = frozenset(
    {"hydra", "paths", "path", "dir", "root", "tags", "logging", "progress", "checkpoint_every"}
)
NON_KEY_SUFFIXES = ("_dir", "_path", "_file", "_root")


def is_non_key_name(name: str) -> bool:
    """True when a config entry of this name never enters an artifact key."""
    return name in NON_KEY_NAMES or name.endswith(NON_KEY_SUFFIXES)


def key_config(cfg: Any) -> Any:
    """A plain copy of `cfg` without the entries, at any depth, that never enter a key."""
    if isinstance(cfg, Mapping):
        return {
            key: key_config(item)
            for key, item in cfg.items()
            if not (isinstance(key, str) and is_non_key_name(key))
        }
    if isinstance(cfg, Sequence) and not isinstance(cfg, str | bytes):
        return [key_config(item) for item in cfg]
    return cfg


def canonical_json(value: Any, where: str = "value") -> str:
    """Canonical JSON (sorted keys, no whitespace, tuples as lists, shortest floats), so equal
    configs give equal text; a type without a stable form is an InputError naming `where`."""
    return json.dumps(
        _normalise(value, where),
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=True,
        allow_nan=True,
    )


def artifact_key(
    stage_type: str,
    schema_version: int,
    stage_cfg: Mapping[str, Any],
    scene_fingerprint: str,
    upstream_keys: Sequence[str],
) -> str:
    """The artifact's key: sha256 hex of the canonical JSON of its inputs (`stage_cfg`
    through `key_config`, `upstream_keys` in order)."""
    payload = {
        "stage": stage_type,
        "schema_version": schema_version,
        "config": _normalise(key_config(stage_cfg), f"{stage_type} config"),
        "scene": scene_fingerprint,
        "upstream": list(upstream_keys),
    }
    return hashlib.sha256(canonical_json(payload).encode("ascii")).hexdigest()


def _normalise(value: Any, where: str) -> Any:
    """Convert to JSON-native types, failing in one line on anything without a stable form."""
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise InputError(f"{where}: key {key!r} must be a string to enter an artifact key")
            out[key] = _normalise(item, f"{where}.{key}")
        return out
    if isinstance(value, Sequence) and not isinstance(value, str | bytes):
        return [_normalise(item, f"{where}[{index}]") for index, item in enumerate(value)]
    if value is None or isinstance(value, str | bool):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value) + 0.0  # adding 0.0 folds -0.0 into 0.0
    raise InputError(
        f"{where} is a {type(value).__name__}; artifact keys accept only "
        "mappings, sequences, str, int, float, bool and None"
    )
