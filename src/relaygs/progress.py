"""Progress bars that suit where they go: live in a terminal, sparse in a log file.

tqdm redraws up to ten times a second; written to a file (a Slurm log, CI, `> run.log`) each
redraw is another carriage-return record, so away from a terminal the bar is redrawn at most
every LOG_INTERVAL_S seconds.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any, TextIO

from tqdm import tqdm

LOG_INTERVAL_S = 30.0  # seconds between redraws when the stream is not a terminal


def is_terminal(stream: TextIO) -> bool:
    """Whether `stream` is an interactive terminal (False for files, pipes and closed streams)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed file
        return False


def progress_bar(
    iterable: Iterable[Any] | None = None, *, stream: TextIO | None = None, **options: Any
) -> tqdm:
    """A tqdm bar on `stream` (stderr by default), throttled to one redraw per LOG_INTERVAL_S
    when that stream is not a terminal; `options` go to tqdm and win over the throttle."""
    stream = sys.stderr if stream is None else stream
    if not is_terminal(stream):
        options.setdefault("mininterval", LOG_INTERVAL_S)
        options.setdefault("maxinterval", LOG_INTERVAL_S)
    return tqdm(iterable, file=stream, **options)
