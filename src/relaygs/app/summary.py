"""Sweep tables: each job's `result.json` as a row, Δ PSNR against the reference, Markdown."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from relaygs.app.result import METRIC_FIELDS, RESULT_FILE, STATUS_FAILED, STATUS_OK
from relaygs.app.unfinished import unfinished_clause, unfinished_runs
from relaygs.app.walk import entries_named
from relaygs.errors import InputError
from relaygs.per_view import is_number

MISSING = "n/a"
SWEEP_COLUMN = "sweep"  # each job's sweep folder (`.`: the report's), where there are several
LEADING_COLUMNS = (
    "job",
    "variant",
    "pipeline",
    "scene",
    "seed",
    "psnr",
    "delta_psnr",
    "psnr_cf",
    "fg_psnr",
    "ssim",
    "train_s_total",
    "train_s_computed",
    "storage_mb",
    "render_fps",
    "num_gaussians",
    "cache_hits",
    "status",
    "error",
)
REQUIRED_FIELDS = ("variant", "job", "pipeline", "scene", "seed", "psnr")  # null where unknown
NUMERIC_FIELDS = (  # the tables sort or compute with them: a finite number or null
    "job",
    *METRIC_FIELDS,
    "train_s_total",
    "train_s_computed",
    "eval_s_total",
    "eval_s_computed",
    "train_s_built_by_job",
    "eval_s_built_by_job",
    "storage_mb",
    "cache_hits",
    "budget.multiplier",
)
MARKDOWN_COLUMNS = (
    ("Variant", "variant", "{}"),
    ("PSNR ↑", "psnr", "{:.2f}"),
    ("Δ PSNR", "delta_psnr", "{:+.2f}"),
    ("PSNR cf ↑", "psnr_cf", "{:.2f}"),
    ("fg-PSNR ↑", "fg_psnr", "{:.2f}"),
    ("SSIM ↑", "ssim", "{:.4f}"),
    ("Train (s)", "train_s_total", "{:.1f}"),
    ("Computed (s)", "train_s_computed", "{:.1f}"),
    ("Storage (MB)", "storage_mb", "{:.2f}"),
    ("FPS", "render_fps", "{:.1f}"),
    ("Cache hits", "cache_hits", "{:.0f}"),
)


def collect_results(sweep_dir: Path) -> pd.DataFrame:
    """One row per `result.json` below `sweep_dir`, by sweep (where several) and job number."""
    paths = entries_named(Path(sweep_dir), RESULT_FILE)
    if not paths:
        unfinished = unfinished_runs(sweep_dir)
        held = f" ({unfinished_clause(sweep_dir, unfinished)})" if unfinished else ""
        raise InputError(f"no {RESULT_FILE} found under {sweep_dir}{held}")
    rows = [
        {"status": STATUS_OK, **_read_result(path), "run_dir": str(path.parent)} for path in paths
    ]
    sweeps = [path.parent.parent.relative_to(sweep_dir).as_posix() for path in paths]
    order = ["job"]
    if set(sweeps) != {"."}:  # a folder of sweeps: each row says whose job it is
        for row, sweep in zip(rows, sweeps, strict=True):
            row[SWEEP_COLUMN] = sweep
        order.insert(0, SWEEP_COLUMN)
    table = pd.DataFrame(rows).sort_values(order, kind="stable", na_position="last")
    return table.reset_index(drop=True)


def _read_result(path: Path) -> dict[str, Any]:
    """One job's result, refused with its path unless readable, flat and holding every
    REQUIRED_FIELDS key and finite numbers (or null) under NUMERIC_FIELDS."""
    try:
        row = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:  # ValueError: bad UTF-8 or bad JSON
        raise InputError(f"{path}: unreadable result ({error})") from error
    if not isinstance(row, dict):
        raise InputError(f"{path}: expected a JSON object")
    missing = [name for name in REQUIRED_FIELDS if name not in row]
    if missing:
        raise InputError(f"{path}: not a job result, it lacks {', '.join(missing)}")
    for name in NUMERIC_FIELDS:
        value = row.get(name)
        if value is not None and not is_number(value):
            raise InputError(f"{path}: {name}: expected a finite number or null, got {value!r}")
    for name, value in row.items():
        if isinstance(value, dict | list):
            expected = "a number, string, bool or null"
            raise InputError(f"{path}: {name}: expected {expected}, got {value!r}")
    return row


def summary_table(results: pd.DataFrame) -> pd.DataFrame:
    """Results with `delta_psnr` (`_delta`) added and the paper's columns first."""
    table = results.copy()
    table["delta_psnr"] = [_delta(table, index) for index in table.index]
    for column in LEADING_COLUMNS:
        if column not in table:
            table[column] = None
    leading = list(LEADING_COLUMNS)
    return table[leading + [c for c in table.columns if c not in leading]]


def markdown_table(table: pd.DataFrame, title: str, notes: Sequence[str] = ()) -> str:
    """The summary as a Markdown table in the paper's form, with the parameters that tell rows
    of one label apart; then the notes, the caller's `notes` and the failed jobs' errors."""
    if "train_s_computed" in table:
        table = table.assign(train_s_computed=computed_in_sweep(table, "train_s_computed"))
    extra = [(name, name, "{}") for name in distinguishing_parameters(table)]
    columns = [MARKDOWN_COLUMNS[0], *extra, *MARKDOWN_COLUMNS[1:]]
    header = "| " + " | ".join(label for label, _, _ in columns) + " |"
    rule = "|" + "|".join(":---" if i <= len(extra) else "---:" for i in range(len(columns))) + "|"
    lines = [f"# {title}", "", header, rule]
    # each column in its narrowest type, as in the CSV: a whole-number setting that some jobs
    # lack (`scene.loader.downscale`) reads 2, not 2.0
    for _, row in table.convert_dtypes().iterrows():
        cells = [markdown_cell(row.get(column), spec) for _, column, spec in columns]
        if row.get("status") == STATUS_FAILED:
            cells[0] += " (failed)"
        lines.append("| " + " | ".join(cells) + " |")
    sharing = sharing_line(table)
    if sharing:
        lines += ["", sharing]
    for note in (absent_reference_line(table), unmatched_reference_line(table)):
        if note:
            lines += ["", note]
    for note in [*shared_model_lines(table), *stage_note_lines(table), *notes]:
        lines += ["", note]
    failed = failed_jobs(table)
    if failed:
        lines += ["", f"{len(failed)} of {len(table)} job(s) failed:", ""]
        lines += [f"- {job.line}" for job in failed]
    return "\n".join(lines) + "\n"


def sharing_line(table: pd.DataFrame) -> str | None:
    """What sharing artifacts saved: stage seconds the sweep computed against the sum of every
    job's whole lineage, and the same with evaluation added (where results record it)."""
    computed = _sum(computed_in_sweep(table, "train_s_computed"))
    lineage = _seconds(table, ("train_s_total",))
    if computed is None or lineage is None or lineage <= 0:
        return None
    sweeps = "these sweeps" if SWEEP_COLUMN in table else "this sweep"
    line = (
        f"Stage time: {computed:.0f} s computed by {sweeps}, {lineage:.0f} s if every job "
        f"built its own lineage (ratio {computed / lineage:.2f})."
    )
    evaluated = _sum(computed_in_sweep(table, "eval_s_computed"))
    alone_all = _seconds(table, ("train_s_total", "eval_s_total"))
    if evaluated is not None and alone_all is not None and alone_all > 0:
        computed_all = computed + evaluated
        line += (
            f" With evaluation: {computed_all:.0f} s against {alone_all:.0f} s "
            f"(ratio {computed_all / alone_all:.2f})."
        )
    return line


def absent_reference_line(table: pd.DataFrame) -> str | None:
    """Why Δ PSNR is n/a when the reference variant the jobs name (`report.reference`: the
    experiment's, or a misspelt one) is none of the sweep's variants; None when each is one."""
    if "reference_variant" not in table or "variant" not in table:
        return None
    variants = set(table["variant"])
    named = table["reference_variant"]
    absent = sorted({ref for ref in named if isinstance(ref, str) and ref and ref not in variants})
    if not absent:
        return None
    listed = ", ".join(str(variant) for variant in dict.fromkeys(table["variant"]))
    quoted = " or ".join(repr(ref) for ref in absent)
    return (
        f"Δ PSNR is {MISSING} against the reference variant {quoted} (report.reference): no "
        f"job is that variant; this sweep's variants are {listed}"
    )


def unmatched_reference_line(table: pd.DataFrame) -> str | None:
    """Why Δ PSNR is n/a for jobs whose reference variant ran, but on other images (another
    scene, downscale or set of test cameras); None when there are none."""
    if "variant" not in table or "psnr" not in table:
        return None
    unmatched = [
        job_name(row)
        for index, row in table.iterrows()
        if is_number(row.get("psnr"))
        and _reference_variant(table, row) in set(table["variant"])
        and _reference_rows(table, index).empty
    ]
    if not unmatched:
        return None
    return (
        f"Δ PSNR is {MISSING} for {', '.join(unmatched)}: no job of its reference variant was "
        "scored on the same images (another scene, downscale or set of test cameras)"
    )


def stage_note_lines(table: pd.DataFrame) -> list[str]:
    """One line per distinct `notes` value (what a stage told the user), naming its jobs."""
    if "notes" not in table:
        return []
    lines = []
    for notes, rows in table.groupby("notes", sort=False):
        if len(rows) == len(table):
            jobs = "every job"
        else:
            jobs = ", ".join(job_name(row) for _, row in rows.iterrows())
        lines.append(f"Note for {jobs}: {notes}")
    return lines


def shared_model_lines(table: pd.DataFrame) -> list[str]:
    """One line per model (`output_key`) that several finished jobs share."""
    if "output_key" not in table:
        return []
    finished = table[table["output_key"].map(lambda key: isinstance(key, str) and bool(key))]
    lines = []
    for key, rows in finished.groupby("output_key", sort=False):
        if len(rows) > 1:
            jobs = ", ".join(job_name(row) for _, row in rows.iterrows())
            why = ""
            if "relay.k" in rows and rows["relay.k"].nunique() > 1:
                why = " (every relay.k at or above the scene's frame count is one segment)"
            lines.append(
                f"Same trained model for {jobs} (artifact {str(key)[:8]}): their settings train "
                f"the same model on this scene{why}"
            )
    return lines


def computed_in_sweep(table: pd.DataFrame, column: str) -> pd.Series | None:
    """Per row, the seconds of `column` (`*_computed`) the job built, before an interruption
    too: its `*_built_by_job` where the result has one (None when neither is there)."""
    built = column.replace("_computed", "_built_by_job")
    if column not in table:
        return None
    if built not in table:
        return table[column]
    return table[built].where(table[built].map(is_number), table[column])


def _sum(values: pd.Series | None) -> float | None:
    return None if values is None else sum(float(v) for v in values if is_number(v))


def _seconds(table: pd.DataFrame, columns: tuple[str, ...]) -> float | None:
    if not set(columns) <= set(table.columns):
        return None
    return sum(_sum(table[column]) for column in columns)


@dataclass(frozen=True)
class FailedJob:
    """A failed row: its job folder and the line that names it (`job_name`: the error)."""

    run_dir: Path
    line: str


def job_name(row: pd.Series) -> str:
    """`job <n> (<variant>)` (a single run: its folder), `... of <sweep>` among several."""
    number = row.get("job")
    if is_number(number):
        name = f"job {number:.0f} ({row.get('variant')})"
    else:
        name = f"{Path(str(row.get('run_dir'))).name} ({row.get('variant')})"
    sweep = row.get(SWEEP_COLUMN)
    return f"{name} of {sweep}" if isinstance(sweep, str) and sweep != "." else name


def failed_jobs(table: pd.DataFrame) -> list[FailedJob]:
    """Every row whose status is failed."""
    if "status" not in table:
        return []
    failed = table[table["status"] == STATUS_FAILED]
    return [
        FailedJob(Path(row["run_dir"]), f"{job_name(row)}: {row.get('error')}")
        for _, row in failed.iterrows()
    ]


def distinguishing_parameters(table: pd.DataFrame) -> list[str]:
    """The sweep, scene, seed and dotted keys that vary where variant labels repeat."""
    if "variant" not in table or table["variant"].is_unique:
        return []
    dotted = (column for column in table.columns if "." in column)
    candidates = [SWEEP_COLUMN, "scene", "seed", *dotted]
    return [
        column
        for column in candidates
        if column in table and table[column].astype(str).nunique() > 1
    ]


def _delta(table: pd.DataFrame, index: Any) -> float | None:
    """Row `index`'s PSNR minus the mean of its scored reference rows, narrowed to its seed,
    sweep and parameter values where some match (the reference variant's own row: the first)."""
    row = table.loc[index]
    if not is_number(row.get("psnr")):
        return None
    pool = _reference_rows(table, index)
    pool = pool[pool["psnr"].map(is_number).astype(bool)]
    for column in ("seed", SWEEP_COLUMN):
        pool = _narrowed(pool, column, row.get(column))
    varying = [column for column in pool.columns if "." in column and pool[column].nunique() > 1]
    if varying and row.get("variant") == _reference_variant(table, row):
        pool = pool.iloc[:1]
    for column in varying:
        pool = _narrowed(pool, column, row.get(column))
    if pool.empty:
        return None
    return float(row["psnr"]) - float(pool["psnr"].astype(float).mean())


def _narrowed(pool: pd.DataFrame, column: str, value: Any) -> pd.DataFrame:
    """The rows of `pool` whose `column` equals `value`, or all of them where none does."""
    if column not in pool:
        return pool
    same = pool[pool[column] == value]
    return same if len(same) else pool


def _reference_rows(table: pd.DataFrame, index: Any) -> pd.DataFrame:
    """Row `index`'s reference variant's rows on the same scene and (where known) `test_set`."""
    row = table.loc[index]
    rows = table[table["variant"] == _reference_variant(table, row)]
    if "scene" in table:
        rows = rows[rows["scene"] == row.get("scene")]
    test_set = row.get("test_set")
    if "test_set" in table and isinstance(test_set, str):
        rows = rows[rows["test_set"].isin([test_set]) | rows["test_set"].isna()]
    return rows


def _reference_variant(table: pd.DataFrame, row: pd.Series) -> Any:
    """The variant row `row` is compared against: its `reference_variant`, else job 0's."""
    reference = row.get("reference_variant")
    return reference if isinstance(reference, str) and reference else table["variant"].iloc[0]


def markdown_cell(value: Any, spec: str) -> str:
    """One Markdown cell: a number formatted with `spec`, a missing value as MISSING."""
    if value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    if spec == "{}":
        return str(value).replace("|", "\\|")
    if not is_number(value):
        return str(value)
    text = spec.format(value)
    if text.startswith("-") and not text.strip("+-0.,"):  # rounds to zero: no "-0.00"
        return spec.format(0.0)
    return text
