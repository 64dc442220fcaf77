"""Progress bars and status lines that suit where they go: live in a terminal, sparse in a log
file (where each redraw is another record), named by job when jobs run side by side."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

from tqdm import tqdm

LOG_INTERVAL_S = 30.0  # seconds between redraws when the stream is not a terminal

_job_label: str | None = None  # the job this process runs, inside `job_label`


@contextmanager
def job_label(label: str | None) -> Iterator[None]:
    """Name `label` on this process's status lines and progress bars while the block runs
    (None: nothing), so that jobs printing side by side can be told apart."""
    global _job_label
    previous, _job_label = _job_label, label
    try:
        yield
    finally:
        _job_label = previous


def labelled(text: str) -> str:
    """`text`, each of its lines led by `[label] ` inside `job_label`."""
    if not _job_label:
        return text
    return "\n".join(f"[{_job_label}] {line}" for line in text.split("\n"))


def print_labelled(text: str, stream: TextIO | None = None) -> None:
    """Print `text`, `labelled`, to `stream` (stdout) in one flushed write with its newline, so
    jobs printing side by side do not interleave (unbuffered `print` writes them apart)."""
    stream = sys.stdout if stream is None else stream
    stream.write(labelled(text) + "\n")
    stream.flush()


def is_terminal(stream: TextIO) -> bool:
    """Whether `stream` is an interactive terminal (False for files, pipes and closed streams)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed file
        return False


def progress_bar(
    iterable: Iterable[Any] | None = None, *, stream: TextIO | None = None, **options: Any
) -> tqdm:
    """A tqdm bar on `stream` (stderr), redrawn every LOG_INTERVAL_S away from a terminal, its
    `desc` led by the job's label; `options` go to tqdm and win over the throttle."""
    stream = sys.stderr if stream is None else stream
    if _job_label and options.get("desc"):
        options["desc"] = f"{_job_label} {options['desc']}"
    if not is_terminal(stream):
        options.setdefault("mininterval", LOG_INTERVAL_S)
        options.setdefault("maxinterval", LOG_INTERVAL_S)
    return tqdm(iterable, file=stream, **options)
