"""Hydra callbacks of a multirun: one sweep per folder at a time, its report when it ends."""

from __future__ import annotations

import sys
import time
import traceback
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple, NoReturn

from filelock import FileLock, Timeout
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from relaygs.app.result import RESULT_FILE, error_line
from relaygs.app.walk import entries_named
from relaygs.commands.report import describe, write_reports
from relaygs.errors import RelayGSError

SWEEP_LOCK_FILE = ".sweep.lock"


class StartedFolder(NamedTuple):
    """A sweep or single run this process started, the override that names its folder and
    whether the command named it (so that the same command run again goes on there)."""

    folder: Path
    named: bool
    override: str = "hydra.sweep.dir"

    @property
    def kind(self) -> str:
        """'sweep' or 'run'."""
        return "sweep" if self.override == "hydra.sweep.dir" else "run"


STARTED_FOLDERS: list[StartedFolder] = []  # what a command stopped by Ctrl-C names


def names_override(hydra_overrides: Iterable[Any], override: str) -> bool:
    """Whether the command line's Hydra overrides (`hydra.overrides.hydra`) set `override`."""
    return any(str(line).partition("=")[0].lstrip("+") == override for line in hydra_overrides)


class SweepFolderLock(Callback):
    """Holds a lock in the sweep folder while the jobs run, so a second sweep there stops at once;
    listed after `SweepSummary` so that it lets go before the summary may end the command."""

    def __init__(self) -> None:
        self._lock: FileLock | None = None

    def __getstate__(self) -> dict[str, Any]:
        """What a parallel launcher sends its workers: the callback without the lock, which
        stays with the launching process (a lock cannot be pickled)."""
        return {**self.__dict__, "_lock": None}

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Take the sweep folder's lock (or end in one line), and record it in STARTED_FOLDERS."""
        sweep_dir = Path(str(config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        lock = FileLock(sweep_dir / SWEEP_LOCK_FILE)
        try:
            lock.acquire(timeout=0)
        except Timeout:
            _stop(
                f"error: another sweep is running in {sweep_dir}: wait for it to end, or give "
                "this one its own hydra.sweep.dir"
            )
        self._lock = lock
        given = OmegaConf.select(config, "hydra.overrides.hydra", default=None) or []
        STARTED_FOLDERS.append(StartedFolder(sweep_dir, names_override(given, "hydra.sweep.dir")))

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        """Let the next sweep in this folder start."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None


class SweepSummary(Callback):
    """On multirun end: `summary.csv`, `summary.md` and `pareto.png` in the sweep folder."""

    def __init__(self) -> None:
        """Note when the sweep starts, to tell its results from an earlier sweep's there."""
        self.started = time.time()

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        """Write the sweep folder's report and name an earlier sweep's jobs in it; exit 1 with
        one line when a job of this sweep failed or the report could not be written."""
        sweep_dir = Path(str(config.hydra.sweep.dir))
        try:
            files = write_reports(sweep_dir)
        except Exception as error:
            if not isinstance(error, RelayGSError):
                traceback.print_exc()
            detail = error if isinstance(error, RelayGSError) else error_line(error)
            _stop(f"error: no sweep summary: {detail}")
        print(describe(files))
        results = entries_named(sweep_dir, RESULT_FILE)
        earlier = [path.parent for path in results if path.stat().st_mtime < self.started]
        if earlier:
            names = ", ".join(str(folder.relative_to(sweep_dir)) for folder in earlier)
            print(
                f"note: the summary also holds {len(earlier)} job(s) of an earlier sweep in "
                f"{sweep_dir}: {names}; give each sweep its own hydra.sweep.dir",
                file=sys.stderr,
            )
        failed = [job.line for job in files.failed if job.run_dir not in earlier]
        if failed:
            total = files.jobs - len(earlier)
            _stop(f"error: {len(failed)} of {total} job(s) failed: {'; '.join(failed)}")


def _stop(line: str) -> NoReturn:
    """Say `line` on stderr and exit 1 (Hydra turns a callback's other exceptions into warnings)."""
    print(line, file=sys.stderr)
    raise SystemExit(1)
