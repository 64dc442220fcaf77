"""`python -m relaygs.run [OVERRIDES]`: the Hydra app. With no arguments it generates the default
synthetic scene (once), runs the `relaygs` pipeline at the `small` budget, evaluates, and
prints the results and where the outputs are. `+experiment=NAME` runs an experiment (sweeps
are multiruns). See docs/experiments.md.

This module is a thin wrapper: the command line is checked up front (one-line errors), then
Hydra composes the config and calls `relaygs.app.task.run_task` for each job.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import hydra
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from relaygs.app.config import resolve_config
from relaygs.app.plan import plan_run
from relaygs.app.prelaunch import check_command_line
from relaygs.app.suite import load_stage_suite
from relaygs.app.task import run_task
from relaygs.errors import RelayGSError
from relaygs.paths import config_dir


def main(argv: Sequence[str] | None = None) -> int:
    """Check the command line, then hand it to Hydra; bad input exits 1 with one line."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        conf = config_dir()
        suite = load_stage_suite()

        def validate(cfg: DictConfig) -> None:
            plan_run(resolve_config(cfg, Path.cwd()), suite.stages, suite.validate)

        check_command_line(args, conf, validate)
    except RelayGSError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    sys.argv = [sys.argv[0], *args]
    try:
        hydra.main(version_base="1.3", config_path=str(conf), config_name="config")(run_job)()
    finally:
        GlobalHydra.instance().clear()
    return 0


def run_job(cfg: DictConfig) -> dict[str, Any]:
    """Hydra's task function: one job with its run dir, launch dir and overrides; a RelayGS
    error ends the process with one line on stderr."""
    hydra_cfg = HydraConfig.get()
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    try:
        return run_task(
            cfg,
            run_dir=Path(hydra_cfg.runtime.output_dir),
            original_cwd=Path(hydra_cfg.runtime.cwd),
            overrides=list(hydra_cfg.overrides.task),
            job=hydra_cfg.job.num if multirun else None,
        )
    except RelayGSError as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(1) from None


if __name__ == "__main__":
    sys.exit(main())
