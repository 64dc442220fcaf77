"""`python -m relaygs.run [OVERRIDES]`: the Hydra app (docs/experiments.md). Every job the command
line would launch is planned up front (one-line errors), then Hydra runs `run_task` for each."""

from __future__ import annotations

import os
import signal
import sys
import traceback
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import hydra
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from hydra.types import RunMode
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException

from relaygs.app.callbacks import STARTED_FOLDERS, StartedFolder, names_override
from relaygs.app.config import resolve_config
from relaygs.app.plan import plan_run
from relaygs.app.prelaunch import (
    LAUNCH_FLAGS,
    JobValidator,
    check_command_line,
    library_error_line,
)
from relaygs.app.result import RESULT_FILE, error_line
from relaygs.app.suite import StageSuite, load_stage_suite
from relaygs.app.sweep_axes import recorded_sweep_axes
from relaygs.app.task import run_task
from relaygs.cli import INTERRUPTED_EXIT
from relaygs.device import usable_device
from relaygs.errors import RERUN_RUN, RelayGSError, resource_error
from relaygs.paths import config_dir
from relaygs.pipeline.fsio import file_identity
from relaygs.shell import path_override

TERMINATED_EXIT = 143  # a command stopped by SIGTERM (`kill PID`, a scheduler): 128 + SIGTERM
HYDRA_FULL_ERROR = "HYDRA_FULL_ERROR"
RUN_DIR = "hydra.run.dir"


def main(argv: Sequence[str] | None = None) -> int:
    """Check the command line, then hand it to Hydra; bad input exits 1 with one line, and so
    does a sweep with a failed job once its summary is written (`SweepSummary`)."""
    args = list(sys.argv[1:] if argv is None else argv)
    terminated, launched = [], []

    def stop_like_ctrl_c(signum: int, frame: object) -> None:
        terminated.append(signum)
        raise KeyboardInterrupt  # the stage names where it stopped and what a rerun resumes

    # installed before the command line is checked (composing every job takes a while), so a
    # Ctrl-C or SIGTERM then also ends with one line and 130/143, not a traceback
    previous = signal.signal(signal.SIGTERM, stop_like_ctrl_c)
    STARTED_FOLDERS.clear()  # an earlier command's, when this process runs several
    try:
        conf = config_dir()
        check_command_line(args, conf, _job_validator(load_stage_suite()))
        # Hydra takes flags only before the overrides: `seed=0 -m k=1,2` goes as `-m seed=0 k=1,2`
        flags = [arg for arg in args if arg in LAUNCH_FLAGS]
        sys.argv = [sys.argv[0], *flags, *(arg for arg in args if arg not in LAUNCH_FLAGS)]
        launched.append(True)
        with _hydra_errors_raised():
            hydra.main(version_base="1.3", config_path=str(conf), config_name="config")(run_job)()
    except RelayGSError as error:  # the command line (a job's own errors end in run_job)
        print(f"error: {error}", file=sys.stderr)
        return 1
    except (HydraException, OmegaConfBaseException) as error:  # before OSError: Hydra's
        # MissingConfigException is one; the libraries' own message, in one line
        print(f"error: {library_error_line(error)}", file=sys.stderr)
        return 1
    except Exception as error:  # a full disk under Hydra's own writes (multirun.yaml) is one
        failure = resource_error(error)  # line; a programming error keeps its traceback
        if failure is None:
            traceback.print_exc()
        else:
            print(f"error: {failure}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as stop:
        started = STARTED_FOLDERS[-1] if STARTED_FOLDERS else None
        print(_interrupted_line(stop, bool(launched), started), file=sys.stderr)
        return TERMINATED_EXIT if terminated else INTERRUPTED_EXIT
    finally:
        signal.signal(signal.SIGTERM, previous)
        GlobalHydra.instance().clear()
    return 0


@contextmanager
def _hydra_errors_raised() -> Iterator[None]:
    """Let an error out of Hydra (HYDRA_FULL_ERROR), so a full disk under its own writes ends
    in one line."""
    before = os.environ.get(HYDRA_FULL_ERROR)
    os.environ[HYDRA_FULL_ERROR] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(HYDRA_FULL_ERROR, None)
        else:
            os.environ[HYDRA_FULL_ERROR] = before


def _interrupted_line(
    stop: KeyboardInterrupt, launched: bool, started: StartedFolder | None
) -> str:
    """The line a stopped command ends with: where it stopped or what a rerun does, and the
    override that reruns in a folder the command did not name."""
    if str(stop):
        line = f"interrupted: {stop}"
    elif launched:
        line = f"interrupted: {RERUN_RUN}"
    else:
        return "interrupted"
    if started is None or started.named:
        return line
    override = path_override(started.override, started.folder)
    return (
        f"{line}; add {override} to the command, so that the {started.kind} goes on in its "
        "folder, not a new one"
    )


def _job_validator(suite: StageSuite) -> JobValidator:
    """The check of one composed job: its run plan, and its device where it runs here."""

    def validate(cfg: DictConfig, runs_here: bool) -> None:
        config = resolve_config(cfg, Path.cwd())
        plan = plan_run(config, suite.stages, suite.validate, suite.accepted_upstream)
        if runs_here:
            usable_device(plan.device, "train.device")

    return validate


def run_job(cfg: DictConfig) -> dict[str, Any] | None:
    """Hydra's task function: one job. A single run's RelayGS error ends it in one line (exit
    1); a sweep job whose failure it recorded in `result.json` returns None, so others run."""
    hydra_cfg = HydraConfig.get()
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    run_dir = Path(hydra_cfg.runtime.output_dir)
    side_by_side = multirun and hydra_cfg.runtime.choices.get("hydra/launcher") != "basic"
    earlier_result = file_identity(run_dir / RESULT_FILE)
    if not multirun:
        named = names_override(hydra_cfg.overrides.hydra, RUN_DIR)
        STARTED_FOLDERS.append(StartedFolder(run_dir, named, RUN_DIR))
    overrides = list(hydra_cfg.overrides.task)
    axes = recorded_sweep_axes(Path(hydra_cfg.sweep.dir), overrides) if multirun else None
    try:
        return run_task(
            cfg,
            run_dir=run_dir,
            original_cwd=Path(hydra_cfg.runtime.cwd),
            overrides=overrides,
            job=hydra_cfg.job.num if multirun else None,
            label=run_dir.name if side_by_side else None,
            axes=axes,
        )
    except Exception as error:
        recorded = file_identity(run_dir / RESULT_FILE) not in (None, earlier_result)
        if multirun and recorded:
            if not isinstance(error, RelayGSError):
                traceback.print_exc()
            print(f"error: job {hydra_cfg.job.num} failed: {error_line(error)}", file=sys.stderr)
            return None
        if isinstance(error, RelayGSError):
            print(f"error: {error}", file=sys.stderr)
            raise SystemExit(1) from None
        raise
