"""`python -m relaygs.report SWEEP_DIR`: (re)write a sweep's summary.csv/md, pareto.png and
psnr_by_frame.png (also as the TensorBoard run `sweep`), summary_mean.* over seeds and
summary_budget.* over budget.multiplier, from its jobs' result.json and per_view.csv files."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from relaygs.app.aggregate import aggregate_markdown, aggregate_table
from relaygs.app.frame_curves import frame_curves, plot_frame_curves
from relaygs.app.marginal import marginal_markdown, marginal_table, varies_budget
from relaygs.app.pareto import plot_pareto
from relaygs.app.prelaunch import recorded_job_count
from relaygs.app.result import RESULT_FILE
from relaygs.app.summary import (
    FailedJob,
    collect_results,
    failed_jobs,
    is_number,
    markdown_table,
    summary_table,
)
from relaygs.app.sweep_board import log_sweep_report
from relaygs.app.unfinished import unfinished_line, unfinished_runs
from relaygs.cli import OneLineErrorParser, one_line_failures, path_argument
from relaygs.errors import InputError
from relaygs.paths import require_folder
from relaygs.pipeline.fsio import publish_text

SUMMARY_CSV = "summary.csv"
SUMMARY_MD = "summary.md"
PARETO_PNG = "pareto.png"
FRAMES_PNG = "psnr_by_frame.png"
MEAN = "summary_mean"
BUDGET = "summary_budget"


@dataclass(frozen=True)
class ReportFiles:
    """The files a report wrote (None where one does not apply), its table and failed jobs."""

    csv: Path
    markdown: Path
    table: str
    pareto: Path | None
    jobs: int
    failed: tuple[FailedJob, ...]
    mean: Path | None = None
    budget: Path | None = None
    frames: Path | None = None
    board: Path | None = None


def write_reports(sweep_dir: Path) -> ReportFiles:
    """Collect the sweep's results and write its tables and plots."""
    sweep_dir = _require_sweep_folder(Path(sweep_dir))
    table = summary_table(collect_results(sweep_dir))
    try:
        return _write_files(table, sweep_dir)
    except OSError as error:
        raise InputError(
            f"cannot write {error.filename or sweep_dir}: {error.strerror or error}"
        ) from error


def _require_sweep_folder(sweep_dir: Path) -> Path:
    """`sweep_dir` if it is a folder but not one run's own (a report would land among its files)."""
    sweep_dir = require_folder(sweep_dir, "sweep folder")
    if (sweep_dir / RESULT_FILE).exists():
        raise InputError(
            f"{sweep_dir} is one run's folder (it holds {RESULT_FILE}), not a sweep folder: "
            "pass the folder that holds the job folders"
        )
    return sweep_dir


def _write_files(table: pd.DataFrame, sweep_dir: Path) -> ReportFiles:
    title = _title(table, sweep_dir)
    curves = frame_curves(table)  # reads every per_view.csv: refuses a damaged one before writing
    csv_path = sweep_dir / SUMMARY_CSV
    _write_csv(table, csv_path)
    markdown_path = sweep_dir / SUMMARY_MD
    planned = recorded_job_count(sweep_dir)
    unfinished = unfinished_line(sweep_dir, unfinished_runs(sweep_dir), len(table), planned)
    markdown = markdown_table(table, title, [unfinished] if unfinished else [])
    publish_text(markdown_path, markdown)
    plottable = zip(table.psnr, table.train_s_total, strict=True)
    plotted = table[[is_number(psnr) and is_number(time) for psnr, time in plottable]]
    pareto = None
    if len(plotted):
        pareto = plot_pareto(
            [float(t) for t in plotted.train_s_total],
            [float(p) for p in plotted.psnr],
            [str(v) for v in plotted.variant],
            sweep_dir / PARETO_PNG,
            title,
        )
    else:
        _remove(sweep_dir / PARETO_PNG)
    frames = plot_frame_curves(curves, sweep_dir / FRAMES_PNG, title)
    if frames is None:
        _remove(sweep_dir / FRAMES_PNG)
    means = aggregate_table(table) if {"scene", "variant"} <= set(table.columns) else None
    repeated = means is not None and not means.empty and (means["seeds"] > 1).any()
    mean_title = f"{title}: mean ± std over seeds"
    mean = _write_table(
        means if repeated else None, sweep_dir / MEAN, aggregate_markdown, mean_title
    )
    marginal = marginal_table(table) if varies_budget(table) else None
    budget_title = f"{title}: what a minute buys"
    budget = _write_table(marginal, sweep_dir / BUDGET, marginal_markdown, budget_title)
    board = log_sweep_report(sweep_dir, [p for p in (pareto, frames) if p is not None], markdown)
    failed = tuple(failed_jobs(table))
    return ReportFiles(
        csv_path, markdown_path, markdown, pareto, len(table), failed, mean, budget, frames, board
    )


def _write_table(
    table: pd.DataFrame | None, stem: Path, markdown: Callable[[pd.DataFrame, str], str], title: str
) -> Path | None:
    """`<stem>.csv` and `<stem>.md` of an optional table; without rows, an earlier report's go."""
    csv_path, markdown_path = stem.with_suffix(".csv"), stem.with_suffix(".md")
    if table is None or table.empty:
        _remove(csv_path, markdown_path)
        return None
    _write_csv(table, csv_path)
    publish_text(markdown_path, markdown(table, title))
    return markdown_path


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry: exit 0, or 1 with one line on stderr (2 on a usage error)."""
    parser = OneLineErrorParser(prog="python -m relaygs.report", description=__doc__)
    parser.add_argument(
        "sweep_dir", type=path_argument, help="a multirun folder holding job folders"
    )
    args = parser.parse_args(argv)
    return one_line_failures(lambda: print(describe(write_reports(args.sweep_dir))))


def describe(files: ReportFiles) -> str:
    """The summary table as written to `summary.md`, then where the report's files are."""
    lines = [files.table.rstrip("\n"), "", f"summary of {files.jobs} job(s):"]
    lines += [f"  {files.markdown}", f"  {files.csv}"]
    for extra in (files.pareto, files.frames):
        if extra is not None:
            lines.append(f"  {extra}")
    for table in (files.mean, files.budget):  # each Markdown table beside its CSV
        if table is not None:
            lines += [f"  {table}", f"  {table.with_suffix('.csv')}"]
    if files.board is not None:
        lines.append(f"  {files.board}  (TensorBoard run `{files.board.name}`: plots and table)")
    return "\n".join(lines)


def _remove(*paths: Path) -> None:
    for path in paths:
        path.unlink(missing_ok=True)


def _write_csv(table: pd.DataFrame, path: Path) -> None:
    """`table` as CSV, each column in its narrowest type (16, not 16.0, beside missing rows)."""
    publish_text(path, table.convert_dtypes().to_csv(index=False))


def _title(table: pd.DataFrame, sweep_dir: Path) -> str:
    """'<experiment> on <scene>' when every job names them alike, else the folder name."""
    experiments = {e if isinstance(e, str) else None for e in table.get("experiment", [None])}
    scenes = {s for s in table.get("scene", []) if isinstance(s, str)}
    experiment = experiments.pop() if len(experiments) == 1 else None
    name = experiment or sweep_dir.name
    return f"{name} on {scenes.pop()}" if len(scenes) == 1 else name
