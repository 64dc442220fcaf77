"""Per-view test metrics: a run's `per_view.csv` (one row per scored test image: frame, camera,
PSNR, SSIM, fg-PSNR) and the per-frame means that show where in time quality drops."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from relaygs.errors import InputError
from relaygs.pipeline.fsio import publish_text

PER_VIEW = "per_view"
"""The key under which an evaluation's metrics hold its ViewRecords (optional for a custom
evaluate function: without it a run writes no per_view.csv)."""
PER_VIEW_FILE = "per_view.csv"
ID_COLUMNS = ("frame", "camera")
METRIC_COLUMNS = ("psnr", "ssim", "fg_psnr")
"""The per-image metrics; a run's psnr, ssim and fg_psnr are their means over the images."""
COLUMNS = (*ID_COLUMNS, *METRIC_COLUMNS)
TENSOR_PREFIX = f"{PER_VIEW}."

ViewRecord = dict[str, Any]
"""{frame: int, camera: int, psnr/ssim/fg_psnr: float or None}."""


def write_per_view(path: Path, records: Iterable[Mapping[str, Any]]) -> Path:
    """Write the records as CSV (a metric that is None as an empty cell), whole or not at all."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(COLUMNS)
    for record in records:
        metrics = [_cell(record.get(name)) for name in METRIC_COLUMNS]
        writer.writerow([int(record["frame"]), int(record["camera"]), *metrics])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    publish_text(path, text.getvalue())
    return path


def read_per_view(path: Path) -> list[ViewRecord]:
    """The records of a `per_view.csv`, refused with its path and line when a header or value
    is not what `write_per_view` writes."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, ValueError) as error:  # ValueError: bad UTF-8
        raise InputError(f"{path}: unreadable per-view metrics ({error})") from error
    rows = list(csv.reader(lines))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise InputError(f"{path}: expected the header {','.join(COLUMNS)}")
    return [_record(path, number, row) for number, row in enumerate(rows[1:], start=2)]


def frame_means(records: Sequence[Mapping[str, Any]], metric: str) -> dict[int, float]:
    """{frame: mean of `metric` over that frame's views that have it}, frames in order."""
    sums: dict[int, list[float]] = {}
    for record in records:
        value = record.get(metric)
        if value is not None:
            sums.setdefault(int(record["frame"]), []).append(float(value))
    return {frame: sum(values) / len(values) for frame, values in sorted(sums.items())}


def to_tensors(records: Sequence[Mapping[str, Any]]) -> dict[str, torch.Tensor]:
    """The records as tensors for an artifact, one per column (`per_view.<column>`: ids int64,
    metrics float64 so stored values read back exactly), a metric's missing values as 0 with
    `per_view.has_<metric>` false there (artifacts hold no NaN)."""
    tensors = {
        f"{TENSOR_PREFIX}{name}": torch.tensor([int(r[name]) for r in records], dtype=torch.int64)
        for name in ID_COLUMNS
    }
    for name in METRIC_COLUMNS:
        values = [record.get(name) for record in records]
        tensors[f"{TENSOR_PREFIX}{name}"] = torch.tensor(
            [0.0 if v is None else float(v) for v in values], dtype=torch.float64
        )
        tensors[f"{TENSOR_PREFIX}has_{name}"] = torch.tensor(
            [v is not None for v in values], dtype=torch.bool
        )
    return tensors


def from_tensors(tensors: Mapping[str, torch.Tensor]) -> list[ViewRecord] | None:
    """The records `to_tensors` stored, or None when the tensors hold none."""
    if f"{TENSOR_PREFIX}frame" not in tensors:
        return None
    columns = {name: tensors[f"{TENSOR_PREFIX}{name}"].tolist() for name in COLUMNS}
    present = {name: tensors[f"{TENSOR_PREFIX}has_{name}"].tolist() for name in METRIC_COLUMNS}
    return [
        {
            **{name: columns[name][i] for name in ID_COLUMNS},
            **{name: columns[name][i] if present[name][i] else None for name in METRIC_COLUMNS},
        }
        for i in range(len(columns["frame"]))
    ]


def _record(path: Path, line: int, row: list[str]) -> ViewRecord:
    """One CSV row as a record (ids as ints, metrics as finite floats or None)."""
    if len(row) != len(COLUMNS):
        raise InputError(f"{path}:{line}: expected {len(COLUMNS)} values, got {len(row)}")
    cells = dict(zip(COLUMNS, row, strict=True))
    try:
        record: ViewRecord = {name: int(cells[name]) for name in ID_COLUMNS}
        for name in METRIC_COLUMNS:
            record[name] = float(cells[name]) if cells[name] else None
    except ValueError as error:
        raise InputError(f"{path}:{line}: expected numbers, got {','.join(row)}") from error
    if any(record[name] is not None and not math.isfinite(record[name]) for name in COLUMNS):
        raise InputError(f"{path}:{line}: expected finite numbers, got {','.join(row)}")
    return record


def _cell(value: Any) -> str:
    """A metric as CSV text: empty for None, else the float's shortest round-trip form."""
    return "" if value is None else repr(float(value))
