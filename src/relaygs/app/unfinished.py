"""Which jobs of a sweep folder the summary lacks: run folders without a result, unstarted."""

from __future__ import annotations

from pathlib import Path

from relaygs.app.result import RESULT_FILE
from relaygs.app.walk import entries_named

HYDRA_FOLDER = ".hydra"  # what Hydra writes into every run folder before the job starts
LISTED_FOLDERS = 5  # folders without a result a note names before it counts the rest


def unfinished_runs(sweep_dir: Path) -> list[Path]:
    """The run folders below `sweep_dir` (with a HYDRA_FOLDER) that hold no `result.json`."""
    return sorted(
        folder.parent
        for folder in entries_named(Path(sweep_dir), HYDRA_FOLDER)
        if folder.is_dir() and not (folder.parent / RESULT_FILE).exists()
    )


def unfinished_line(
    sweep_dir: Path, unfinished: list[Path], finished: int, planned: int | None
) -> str | None:
    """Which run folders the table leaves out for want of a result, and how many of the
    `planned` jobs (None: not known) have no folder; None when the table misses nothing."""
    parts = [unfinished_clause(sweep_dir, unfinished)] if unfinished else []
    started = finished + len(unfinished)
    if planned is not None and planned > started:
        parts.append(
            f"{planned - started} of the {planned} job(s) the sweep planned have no folder "
            "(not started)"
        )
    return f"Not in the table: {'; '.join(parts)}." if parts else None


def unfinished_clause(sweep_dir: Path, unfinished: list[Path]) -> str:
    """`<n> run folder(s) hold no result.json (...): a, b` naming at most LISTED_FOLDERS."""
    names = [
        folder.relative_to(sweep_dir).as_posix() if folder != sweep_dir else str(folder)
        for folder in unfinished
    ]
    listed = ", ".join(names[:LISTED_FOLDERS])
    if len(names) > LISTED_FOLDERS:
        listed += f" and {len(names) - LISTED_FOLDERS} more"
    return (
        f"{len(names)} run folder(s) hold no {RESULT_FILE} (interrupted, still running or "
        f"stopped before writing it): {listed}"
    )
