"""TensorBoard logging for one job: stage scalars and images, captioned previews, notes and the
HParams entry. Tags group by their first part: `eval/`, `result/` (what HParams reads),
`reused/` (notes), and per stage `train/`, `train_gaussians/` (counts) and `train_lr/`."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import torch
from torch.utils.tensorboard import SummaryWriter

from relaygs.app.captions import captioned_row
from relaygs.app.hparams import (
    HParamValue,
    experiment_summary,
    metric_tag,
    session_end_summary,
    session_start_summary,
)
from relaygs.app.sweep_axes import SweepAxes
from relaygs.error_map import ERROR_FULL_SCALE, error_image
from relaygs.errors import RERUN_RUN, ResourceError

COUNT_SCALARS = ("num_bg", "num_fg", "fg_fraction")  # count Gaussians, not measure the fit


def training_tag(stage: str, name: str) -> str:
    """Where a stage's training scalar goes: `train_lr/<stage>/` for a learning rate (`lr/x`),
    `train_gaussians/<stage>/` for COUNT_SCALARS, else `train/<stage>/<name>`."""
    if name.startswith("lr/"):
        return f"train_lr/{stage}/{name.removeprefix('lr/')}"
    if name in COUNT_SCALARS:
        return f"train_gaussians/{stage}/{name}"
    return f"train/{stage}/{name}"


class TensorBoardLog:
    """One SummaryWriter in the job's log dir, callable as a stage log sink; failures name it."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = Path(log_dir)
        _QuietWriterThreads.install()
        self.writer = SummaryWriter(log_dir=str(self.log_dir))
        self._failed = False

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Re-raise a failed write naming the log folder, so it ends the job in one line."""
        try:
            yield
        except OSError as error:
            self._failed = True
            if not self.log_dir.is_dir():
                raise ResourceError(
                    f"TensorBoard log folder {self.log_dir} was removed while the job ran: "
                    f"{RERUN_RUN}"
                ) from error
            if error.errno is None:
                raise
            raise OSError(error.errno, error.strerror, str(self.log_dir)) from error

    def __call__(
        self,
        stage: str,
        step: int,
        scalars: Mapping[str, float],
        images: Mapping[str, torch.Tensor] | None = None,
    ) -> None:
        """Log a stage's scalars under `training_tag` and its images as `train/<stage>/<name>`."""
        for name, value in scalars.items():
            self.add_scalar(training_tag(stage, name), value, step)
        for name, image in (images or {}).items():
            self.add_image(f"train/{stage}/{name}", image, step)

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        """Log one scalar."""
        with self._writing():
            self.writer.add_scalar(tag, float(value), step)

    def add_text(self, tag: str, text: str, step: int = 0) -> None:
        """Log a Markdown note (TensorBoard's Text tab)."""
        with self._writing():
            self.writer.add_text(tag, text, step)

    def add_image(self, tag: str, image: torch.Tensor, step: int) -> None:
        """Log one [H,W,3] float image (values clamped to [0,1])."""
        pixels = image.detach().float().cpu().clamp(0.0, 1.0)
        with self._writing():
            self.writer.add_image(tag, pixels, step, dataformats="HWC")

    def add_comparison(
        self, tag: str, render: torch.Tensor, truth: torch.Tensor, frame: int
    ) -> None:
        """Log a render, its ground truth and its error image side by side, captioned."""
        render, truth = render.detach().float().cpu(), truth.detach().float().cpu()
        panels = [
            (f"render, frame {frame}", render),
            ("truth", truth),
            (f"error (0 to {ERROR_FULL_SCALE:g}+)", error_image(render, truth)),
        ]
        self.add_image(tag, captioned_row(panels), frame)

    def add_hparams(
        self,
        params: Mapping[str, HParamValue],
        metrics: Mapping[str, float | None],
        axes: SweepAxes,
        group: str,
    ) -> None:
        """Write the HParams entry as trial `group`, each metric as the scalar `result/<name>`."""
        finite = {metric_tag(name): float(v) for name, v in metrics.items() if v is not None}
        with self._writing():
            file_writer = self.writer._get_file_writer()
            file_writer.add_summary(experiment_summary(params, axes))
            file_writer.add_summary(session_start_summary(params, axes, group))
            for tag, value in finite.items():
                self.writer.add_scalar(tag, value, 0)
            file_writer.add_summary(session_end_summary())

    def close(self) -> None:
        """Flush and close the event file (after a failed write only release it)."""
        if self._failed:
            with contextlib.suppress(OSError):
                self.writer.close()
            return
        with self._writing():
            self.writer.close()


class _QuietWriterThreads:
    """A `threading.excepthook` that leaves TensorBoard's writer thread's OSError unprinted (the
    job's next call raises it again) and hands anything else to the hook it replaced."""

    def __init__(self, previous: Callable[[Any], object]) -> None:
        self.previous = previous

    def __call__(self, args: Any) -> None:
        writer_thread = type(args.thread).__module__.startswith("tensorboard.")
        if not (writer_thread and isinstance(args.exc_value, OSError)):
            self.previous(args)

    @classmethod
    def install(cls) -> None:
        """Put the hook in front of the current one, once."""
        if not isinstance(threading.excepthook, cls):
            threading.excepthook = cls(threading.excepthook)
