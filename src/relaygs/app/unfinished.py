"""Which jobs of a sweep folder the summary table lacks: run folders that hold no
`result.json` (a job interrupted, still running, or stopped before writing it) and, given how
many jobs the sweep planned, those that never started."""

from __future__ import annotations

from pathlib import Path

from relaygs.app.result import RESULT_FILE
from relaygs.app.walk import entries_named

HYDRA_FOLDER = ".hydra"
"""What Hydra writes into every run folder it creates, before the job starts."""
LISTED_FOLDERS = 5
"""How many folders without a result a note names before it counts the rest."""


def unfinished_runs(sweep_dir: Path) -> list[Path]:
    """The run folders below `sweep_dir` (those Hydra gave a HYDRA_FOLDER) that hold no
    `result.json`: jobs that were interrupted, are still running or died before writing it."""
    return sorted(
        folder.parent
        for folder in entries_named(Path(sweep_dir), HYDRA_FOLDER)
        if folder.is_dir() and not (folder.parent / RESULT_FILE).exists()
    )


def unfinished_line(
    sweep_dir: Path, unfinished: list[Path], finished: int, planned: int | None
) -> str | None:
    """Which run folders the table leaves out for want of a result, and how many of the
    `planned` jobs of the sweep (None: not known) have no folder at all, not having started:
    `planned` less the folders with a result (`finished`) or without one, an earlier sweep's
    in the same folder included (None when the table misses nothing)."""
    parts = [unfinished_clause(sweep_dir, unfinished)] if unfinished else []
    started = finished + len(unfinished)
    if planned is not None and planned > started:
        parts.append(
            f"{planned - started} of the {planned} job(s) the sweep planned have no folder "
            "(not started)"
        )
    return f"Not in the table: {'; '.join(parts)}." if parts else None


def unfinished_clause(sweep_dir: Path, unfinished: list[Path]) -> str:
    """`<n> run folder(s) hold no result.json (interrupted, ...): a, b, c` with at most
    LISTED_FOLDERS names, relative to `sweep_dir`."""
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
