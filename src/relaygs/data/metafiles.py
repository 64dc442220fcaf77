"""Reading the text and JSON files of a scene folder with one-line errors; declared effects."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from relaygs.data.effects import parse_effects
from relaygs.data.sources import regular_file_status
from relaygs.errors import InputError

SCENE_JSON = "scene.json"


def read_text(path: Path) -> str:
    """A UTF-8 text file's contents without a byte-order mark; missing, irregular, unreadable or
    not UTF-8 is an InputError naming the file."""
    try:
        regular_file_status(path)
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"missing file: {path}") from None
    except OSError as error:
        raise InputError(f"cannot read {path} ({error.strerror})") from None
    except UnicodeDecodeError as error:
        raise InputError(
            f"{path}: not UTF-8 text (byte 0x{error.object[error.start]:02x} at offset "
            f"{error.start})"
        ) from None


def read_json(path: Path) -> Any:
    """Parse a JSON file; a missing, unreadable or malformed file is an InputError naming it."""
    text = read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise InputError(
            f"{path}: malformed JSON at line {error.lineno} column {error.colno}: {error.msg}"
        ) from None


def scene_declaration(root: Path) -> dict[str, Any] | None:
    """scene.json's object (None without the file); any other JSON value is an InputError."""
    path = root / SCENE_JSON
    if not path.exists():
        return None
    declaration = read_json(path)
    if not isinstance(declaration, dict):
        raise InputError(
            f"{path}: expected a JSON object with fields such as effects and test_cameras"
        )
    return declaration


def declared_effects(root: Path) -> frozenset[str]:
    """Effects a scene folder declares in scene.json (none when the file is absent)."""
    path = root / SCENE_JSON
    effects = (scene_declaration(root) or {}).get("effects", [])
    if not isinstance(effects, list):
        raise InputError(f"{path}: field 'effects' must be a list of effect names")
    return parse_effects(effects, source=f"{path} field 'effects'")


def declared_test_cameras(root: Path) -> tuple[int, ...] | None:
    """scene.json's 'test_cameras' (None without it), so an export keeps its source's split."""
    declaration = scene_declaration(root) or {}
    if "test_cameras" not in declaration:
        return None
    ids = declaration["test_cameras"]
    valid = isinstance(ids, list) and all(
        isinstance(camera_id, int) and not isinstance(camera_id, bool) and camera_id >= 0
        for camera_id in ids
    )
    if not valid:
        raise InputError(
            f"{root / SCENE_JSON}: field 'test_cameras' must be a list of camera ids "
            f"(integers >= 0), got {ids!r}"
        )
    return tuple(sorted(set(ids)))
