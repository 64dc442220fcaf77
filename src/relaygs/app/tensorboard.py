"""TensorBoard logging for one job: a sink for the stages' scalars and images, render vs
ground-truth previews, and the HParams entry that lets `tensorboard --logdir SWEEP` compare jobs.

HParams rules (DESIGN.md): the config is flattened to dotted keys, None is written as "None",
every job logs the same keys, and the hparams go into the job's own log dir.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import torch
from torch.utils.tensorboard import SummaryWriter
from torch.utils.tensorboard.summary import hparams

from relaygs.error_map import error_image
from relaygs.errors import RERUN_RUN, ResourceError

HParamValue = bool | int | float | str


class TensorBoardLog:
    """One SummaryWriter in the job's log dir; callable as a stage log sink.

    TensorBoard writes from a thread of its own and raises a failed write's OSError at the
    next call; every call here names the log folder in it (a full disk, a folder removed while
    the job ran), and the thread itself stays quiet (`_QuietWriterThreads`).
    """

    def __init__(self, log_dir: Path) -> None:
        """Open the writer on `log_dir` (created if missing)."""
        self.log_dir = Path(log_dir)
        _QuietWriterThreads.install()
        self.writer = SummaryWriter(log_dir=str(self.log_dir))
        self._failed = False

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Re-raise a failed write naming the log folder (TensorBoard names no path, or the
        event file's as bytes), so it ends the job in one line."""
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
        """Log a stage's scalars as `<stage>/<name>` and its [H,W,3] images in [0,1]."""
        with self._writing():
            for name, value in scalars.items():
                self.writer.add_scalar(f"{stage}/{name}", float(value), step)
        for name, image in (images or {}).items():
            self.add_image(f"{stage}/{name}", image, step)

    def add_image(self, tag: str, image: torch.Tensor, step: int) -> None:
        """Log one [H,W,3] float image (values clamped to [0,1])."""
        pixels = image.detach().float().cpu().clamp(0.0, 1.0)
        with self._writing():
            self.writer.add_image(tag, pixels, step, dataformats="HWC")

    def add_comparison(
        self, tag: str, render: torch.Tensor, truth: torch.Tensor, step: int
    ) -> None:
        """Log a render, its ground truth and the render's error image (`error_image`) side by
        side, in that order."""
        render, truth = render.detach().float().cpu(), truth.detach().float().cpu()
        self.add_image(tag, torch.cat([render, truth, error_image(render, truth)], dim=1), step)

    def add_hparams(
        self, params: Mapping[str, HParamValue], metrics: Mapping[str, float | None]
    ) -> None:
        """Write the HParams entry into this job's own log dir, with each metric as a scalar
        under its own tag (missing metrics are skipped)."""
        finite = {f"result/{name}": float(v) for name, v in metrics.items() if v is not None}
        experiment, session_start, session_end = hparams(dict(params), finite)
        with self._writing():
            file_writer = self.writer._get_file_writer()
            for summary in (experiment, session_start, session_end):
                file_writer.add_summary(summary)
            for tag, value in finite.items():
                self.writer.add_scalar(tag, value, 0)

    def close(self) -> None:
        """Flush and close the event file; after a failed write only release it, so the error
        that ended the job is the one reported."""
        if self._failed:
            with contextlib.suppress(OSError):
                self.writer.close()
            return
        with self._writing():
            self.writer.close()


class _QuietWriterThreads:
    """A `threading.excepthook` that leaves an OSError of TensorBoard's writer thread unprinted
    (the writer raises it again at the job's next call, which reports it) and hands every
    other thread's exception to the hook it replaced."""

    def __init__(self, previous: Callable[[Any], object]) -> None:
        self.previous = previous

    def __call__(self, args: Any) -> None:
        """Drop a TensorBoard writer thread's OSError; pass anything else on."""
        writer_thread = type(args.thread).__module__.startswith("tensorboard.")
        if not (writer_thread and isinstance(args.exc_value, OSError)):
            self.previous(args)

    @classmethod
    def install(cls) -> None:
        """Put the hook in front of the current one, once."""
        if not isinstance(threading.excepthook, cls):
            threading.excepthook = cls(threading.excepthook)


def flatten_config(config: Mapping[str, Any], prefix: str = "") -> dict[str, HParamValue]:
    """Nested config as {dotted key: value}; None → "None", lists → their JSON text."""
    flat: dict[str, HParamValue] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_config(value, f"{name}."))
        else:
            flat[name] = hparam_value(value)
    return flat


def hparam_value(value: Any) -> HParamValue:
    """A value TensorBoard's HParams accepts: None → "None", containers → JSON text."""
    if value is None:
        return "None"
    if isinstance(value, bool | int | float | str):
        return value
    return json.dumps(value, sort_keys=True, default=str)
