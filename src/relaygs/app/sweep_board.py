"""The sweep-level TensorBoard run: the report's plots and table beside the jobs' runs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import torch

from relaygs.app.tensorboard import TensorBoardLog

SWEEP_RUN = "sweep"  # the run's folder in the sweep folder, and so its name in TensorBoard
EVENT_FILES = "events.out.tfevents.*"


def log_sweep_report(sweep_dir: Path, figures: Sequence[Path], table: str) -> Path:
    """Write `figures` and `table` as run SWEEP_RUN (replacing an earlier report's); its folder."""
    folder = Path(sweep_dir) / SWEEP_RUN
    for old in folder.glob(EVENT_FILES):
        old.unlink()
    log = TensorBoardLog(folder)
    try:
        for figure in figures:
            log.add_image(f"sweep/{figure.stem}", _read_png(figure), 0)
        log.add_text("sweep/summary", table)
    finally:
        log.close()
    return folder


def _read_png(path: Path) -> torch.Tensor:
    pixels = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if pixels is None:
        raise OSError(f"cannot read the image {path}")
    rgb = cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)
    return torch.from_numpy(rgb).float() / 255.0
