"""Where every benchmark's figures go besides the terminal: an optional JSON report."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder


def json_target(value: str) -> Path:
    """argparse type of `--json`: a path that can be written once the benchmark is done, checked
    before it starts (so hours of timing are not lost to a bad path)."""
    path = Path(value).expanduser().absolute()
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder, expected a file path")
    try:
        require_creatable_folder(path.parent, f"cannot write {path}")
    except InputError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return path


def save_json(path: Path | None, report: dict[str, Any]) -> None:
    """Write `report` as indented JSON to `path` (its folder is created); nothing when None."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2))
