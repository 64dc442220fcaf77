"""Per-view test metrics: a run's `per_view.csv` and per-frame means (where quality drops)."""

from __future__ import annotations

import csv
import io
import math
import numbers
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import torch

from relaygs.errors import InputError
from relaygs.pipeline.fsio import publish_text

PER_VIEW = "per_view"  # where an evaluation's metrics hold its ViewRecords (optional)
PER_VIEW_FILE = "per_view.csv"
ID_COLUMNS = ("frame", "camera")
METRIC_COLUMNS = ("psnr", "ssim", "fg_psnr")  # a run's metrics are their means
COLUMNS = (*ID_COLUMNS, *METRIC_COLUMNS)
TENSOR_PREFIX = f"{PER_VIEW}."

ViewRecord = dict[str, Any]  # {frame: int, camera: int, psnr/ssim/fg_psnr: float or None}


def checked_records(records: Iterable[Mapping[str, Any]]) -> list[ViewRecord]:
    """The records as ViewRecords, refused in one line unless each has int ids and finite (or
    None) metrics: a diverged model's NaN must not be stored."""
    checked = []
    for index, record in enumerate(records):
        missing = [name for name in COLUMNS if name not in record]
        if missing:
            raise InputError(f"per-view record {index} lacks {', '.join(missing)}: {record!r}")
        ids = {name: record[name] for name in ID_COLUMNS}
        if not all(_is_int(value) for value in ids.values()):
            raise InputError(f"per-view record {index}: frame and camera must be ints: {ids!r}")
        for name in METRIC_COLUMNS:
            value = record[name]
            if value is not None and not is_number(value):
                raise InputError(
                    f"per-view record {index} (frame {ids['frame']}, camera {ids['camera']}): "
                    f"{name} must be a finite number or None, got {value!r}"
                )
        checked.append({name: record[name] for name in COLUMNS})
    return checked


def write_per_view(path: Path, records: Iterable[Mapping[str, Any]]) -> Path:
    """Write the checked records as CSV (None as an empty cell), whole or not at all."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(COLUMNS)
    for record in checked_records(records):
        metrics = [_cell(record[name]) for name in METRIC_COLUMNS]
        writer.writerow([int(record["frame"]), int(record["camera"]), *metrics])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    publish_text(path, text.getvalue())
    return path


def read_per_view(path: Path) -> list[ViewRecord]:
    """The records of a `per_view.csv`, refused with its path and line where it is damaged."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, ValueError) as error:  # ValueError: bad UTF-8
        raise InputError(f"{path}: unreadable per-view metrics ({error})") from error
    rows = list(csv.reader(lines))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise InputError(f"{path}: expected the header {','.join(COLUMNS)}")
    return [_record(path, number, row) for number, row in enumerate(rows[1:], start=2)]


def frame_means(records: Iterable[Mapping[str, Any]], metric: str) -> dict[int, float]:
    """{frame: mean of `metric` over that frame's views that have it}, frames in order."""
    return means_by_key(
        (int(record["frame"]), float(record[metric]))
        for record in records
        if record.get(metric) is not None
    )


def means_by_key(pairs: Iterable[tuple[int, float]]) -> dict[int, float]:
    """{key: mean of its values} over (key, value) pairs, keys in order."""
    values: dict[int, list[float]] = {}
    for key, value in pairs:
        values.setdefault(key, []).append(value)
    return {key: sum(group) / len(group) for key, group in sorted(values.items())}


def to_tensors(records: Iterable[Mapping[str, Any]]) -> dict[str, torch.Tensor]:
    """The checked records as artifact tensors `per_view.<column>` (float64: exact), a missing
    metric as 0 with `per_view.has_<metric>` false there (no NaN)."""
    checked = checked_records(records)
    tensors = {
        f"{TENSOR_PREFIX}{name}": torch.tensor([r[name] for r in checked], dtype=torch.int64)
        for name in ID_COLUMNS
    }
    for name in METRIC_COLUMNS:
        values = [record[name] for record in checked]
        tensors[f"{TENSOR_PREFIX}{name}"] = torch.tensor(
            [0.0 if v is None else float(v) for v in values], dtype=torch.float64
        )
        tensors[f"{TENSOR_PREFIX}has_{name}"] = torch.tensor(
            [v is not None for v in values], dtype=torch.bool
        )
    return tensors


def from_tensors(tensors: Mapping[str, torch.Tensor]) -> list[ViewRecord] | None:
    """The records `to_tensors` stored (None if none), refused if the columns do not match."""
    names = [f"{TENSOR_PREFIX}{name}" for name in COLUMNS]
    names += [f"{TENSOR_PREFIX}has_{name}" for name in METRIC_COLUMNS]
    if names[0] not in tensors:
        return None
    lengths = {tensors[name].numel() if name in tensors else -1 for name in names}
    if len(lengths) != 1:
        raise InputError(f"per-view tensors {', '.join(names)} are incomplete or unequal")
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
    return "" if value is None else repr(float(value))


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    """A finite real number, numpy's too (bools are not numbers here)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
