"""Hydra callbacks of a multirun: one sweep at a time per sweep folder, and the sweep's tables
and Pareto plot when it ends."""

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

from relaygs.app.result import error_line
from relaygs.app.summary import results_written_before
from relaygs.commands.report import describe, write_reports
from relaygs.errors import RelayGSError

SWEEP_LOCK_FILE = ".sweep.lock"


class StartedFolder(NamedTuple):
    """A sweep or single run this process started: its folder, the override that names it
    (`hydra.sweep.dir` or `hydra.run.dir`) and whether the command named it, so that the same
    command run again goes on in that folder."""

    folder: Path
    named: bool
    override: str = "hydra.sweep.dir"

    @property
    def kind(self) -> str:
        """'sweep' or 'run'."""
        return "sweep" if self.override == "hydra.sweep.dir" else "run"


STARTED_FOLDERS: list[StartedFolder] = []
"""The sweeps this process started, as `SweepFolderLock` took their folders, and its single
runs, as they started: what a command stopped by Ctrl-C names for its rerun
(`relaygs.commands.run` empties it before each launch)."""


def names_override(hydra_overrides: Iterable[Any], override: str) -> bool:
    """Whether the command line's Hydra overrides (`hydra.overrides.hydra`) set `override`
    (`hydra.run.dir=...`, say)."""
    return any(str(line).partition("=")[0].lstrip("+") == override for line in hydra_overrides)


class SweepFolderLock(Callback):
    """Holds a lock in the sweep folder while the multirun's jobs run: a second sweep started
    in the same folder (the same `hydra.sweep.dir`) stops at once instead of writing its jobs
    over the first one's. Listed after `SweepSummary`, so its end comes first: the lock is
    released before the summary, which may end the command (a failed job)."""

    def __init__(self) -> None:
        """No lock yet: it is taken when the multirun starts."""
        self._lock: FileLock | None = None

    def __getstate__(self) -> dict[str, Any]:
        """What a parallel launcher sends its workers with each job: the callback without the
        lock, which stays with the launching process (a lock cannot be pickled)."""
        return {**self.__dict__, "_lock": None}

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Take the sweep folder's lock, or end the command with one line if a sweep holds it;
        record the folder in `STARTED_FOLDERS`."""
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
        """Note when the sweep starts (Hydra makes its callbacks before the first job), to
        tell this sweep's results from those an earlier sweep left in the same folder."""
        self.started = time.time()

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        """Write the report of the sweep folder; name the jobs in it that an earlier sweep
        ran; when a job of this sweep failed, or the report could not be written (a sweep
        without its summary is no success), say which on stderr and exit with status 1."""
        sweep_dir = Path(str(config.hydra.sweep.dir))
        try:
            files = write_reports(sweep_dir)
        except Exception as error:
            if not isinstance(error, RelayGSError):
                traceback.print_exc()
            detail = error if isinstance(error, RelayGSError) else error_line(error)
            _stop(f"error: no sweep summary: {detail}")
        print(describe(files))
        earlier = results_written_before(sweep_dir, self.started)
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
    """Say `line` on stderr and end the command with status 1: Hydra turns a callback's
    exception into a warning, but not SystemExit."""
    print(line, file=sys.stderr)
    raise SystemExit(1)
