"""Where every benchmark's figures go besides the terminal: an optional JSON report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def save_json(path: Path | None, report: dict[str, Any]) -> None:
    """Write `report` as indented JSON to `path` (its folder is created); nothing when None."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2))
