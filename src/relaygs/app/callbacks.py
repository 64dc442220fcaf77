"""Hydra callback that writes the sweep's tables and Pareto plot when a multirun ends."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from relaygs.errors import RelayGSError
from relaygs.report import describe, write_reports


class SweepSummary(Callback):
    """On multirun end: `summary.csv`, `summary.md` and `pareto.png` in the sweep folder."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        """Write the report of the sweep folder (a failure to write it is reported, not
        raised); when a job failed, say which on stderr and exit with status 1."""
        sweep_dir = Path(str(config.hydra.sweep.dir))
        try:
            files = write_reports(sweep_dir)
        except RelayGSError as error:
            print(f"error: no sweep summary: {error}", file=sys.stderr)
            return
        print(describe(files))
        if files.failed:
            failed = "; ".join(files.failed)
            print(
                f"error: {len(files.failed)} of {files.jobs} job(s) failed: {failed}",
                file=sys.stderr,
            )
            # Hydra turns a callback's exception into a warning; SystemExit ends the command.
            raise SystemExit(1)
