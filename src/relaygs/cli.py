"""Command-line plumbing the relaygs tools share: a start that imports the tool only once
running, usage errors as one line, checked counts, a quiet end when the reader of their output
goes away or Ctrl-C stops them."""

from __future__ import annotations

import argparse
import importlib
import io
import math
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from relaygs.errors import RERUN_COMMAND, InputError, RelayGSError, resource_error
from relaygs.paths import require_creatable_folder

BROKEN_PIPE_EXIT = 141
"""128 + SIGPIPE: what a shell tool returns when its reader closed the pipe (`... | head`)."""

INTERRUPTED_EXIT = 130
"""128 + SIGINT: what a command stopped by Ctrl-C returns, as shells expect."""


def start_tool(module: str) -> NoReturn:
    """Exit with the status of `module`'s `main()`, imported only now, so that a Ctrl-C while
    torch and Hydra load ends with one line and INTERRUPTED_EXIT."""
    if isinstance(sys.stdout, io.TextIOWrapper):  # a Δ on a latin-1 terminal: escaped, no error
        sys.stdout.reconfigure(errors="backslashreplace")
    try:
        status = run_tool(importlib.import_module(module).main)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        status = INTERRUPTED_EXIT
    # the work is done: a Ctrl-C while the interpreter shuts down would end a finished
    # render with status 130 and no word
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise SystemExit(status)


class OneLineErrorParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one stderr line (exit 2), without the usage."""

    def error(self, message: str) -> NoReturn:
        """Print `error: message` with where to find help, and exit 2."""
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def int_at_least(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """argparse type of an integer >= `minimum` (and <= `maximum`), refused, not clamped."""
    expected = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"expected an integer {expected}, got {text!r}")
        return value

    return parse


def positive_float(text: str) -> float:
    """argparse type of a rate such as `--fps`: a finite number above 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def camera_ids(text: str) -> tuple[int, ...]:
    """argparse type of camera ids, `1,5` or `[1,5]` (`[]` for none); an empty value (an unset
    shell variable) is refused rather than taken as no test cameras."""
    if text.replace(" ", "") == "[]":
        return ()
    items = [item.strip() for item in text.strip().removeprefix("[").removesuffix("]").split(",")]
    if not all(item.isascii() and item.isdecimal() for item in items):
        raise argparse.ArgumentTypeError(
            f"expected camera ids separated by commas, e.g. 0,10, got {text!r}"
        )
    return tuple(int(item) for item in items)


def path_argument(value: str) -> Path:
    """argparse type of a path: any non-blank text (an empty one would mean the current folder)."""
    if not value.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {value!r}")
    return Path(value)


def writable_file(value: str) -> Path:
    """argparse type of an output file, checked writable before the work starts."""
    path = path_argument(value).expanduser().absolute()
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder, expected a file path")
    try:
        require_creatable_folder(path.parent, f"cannot write {path}")
    except InputError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return path


def run_tool(main: Callable[[], int]) -> int:
    """Run a tool's `main` and return its exit status; a reader that stopped early (`ls | head`)
    ends it with BROKEN_PIPE_EXIT instead of a traceback."""
    try:
        try:
            return main()
        finally:
            sys.stdout.flush()  # buffered output meets the closed pipe here, not at exit
    except BrokenPipeError:
        # the interpreter flushes stdout again when it exits: give it somewhere to go
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return BROKEN_PIPE_EXIT


def one_line_failures(
    work: Callable[[], int | None], bad_input_exit: int = 1, where: str = ""
) -> int:
    """`work()`'s exit status (None: 0); bad input (a RelayGSError) ends with one `error:` line and
    `bad_input_exit`, a full disk or failed allocation with one line naming `where` and 1."""
    try:
        return work() or 0
    except RelayGSError as error:
        print(f"error: {error}", file=sys.stderr)
        return bad_input_exit
    except (OSError, MemoryError, RuntimeError) as error:
        failure = resource_error(error, where, rerun=RERUN_COMMAND)
        if failure is None:
            raise  # a bug keeps its traceback
        print(f"error: {failure}", file=sys.stderr)
        return 1
