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
    """Exit with the status of `module`'s `main()`, imported only now: the `python -m relaygs.X`
    entry modules are this call alone, so that a Ctrl-C while torch and Hydra load (one to three
    seconds) ends with one line and INTERRUPTED_EXIT, as it does once the tool runs."""
    escape_unencodable_output()
    try:
        status = run_tool(importlib.import_module(module).main)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        status = INTERRUPTED_EXIT
    # the work is done: a Ctrl-C while the interpreter shuts down would end a finished
    # render with status 130 and no word
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise SystemExit(status)


def escape_unencodable_output() -> None:
    """Make stdout write what its encoding cannot hold (a table's Δ or ↑ on a latin-1 terminal,
    or redirected to a file under a Windows code page) as backslash escapes, as stderr does,
    instead of ending the tool with UnicodeEncodeError."""
    if isinstance(sys.stdout, io.TextIOWrapper):
        sys.stdout.reconfigure(errors="backslashreplace")


class OneLineErrorParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are a single stderr line (exit status 2), without
    argparse's usage block; its sub-command parsers are of the same class (argparse's default)."""

    def error(self, message: str) -> NoReturn:
        """Print `error: message` with where to find help, and exit 2."""
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def int_at_least(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """argparse type of an integer option that must be >= `minimum` (and <= `maximum` when
    given): a value outside is refused in one line rather than silently clamped."""
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
    """argparse type of a rate such as `--fps`: a finite number above 0, else refused in one
    line (`nan`, `inf` and 0 would only fail once the work is done)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def camera_ids(text: str) -> tuple[int, ...]:
    """argparse type of a list of camera ids, `1,5` (a pasted Hydra list `[1,5]` too; `[]` for
    none), as the `scene.loader.test_cameras` a run was given; an empty value is refused (an
    unset shell variable must not mean "no test cameras")."""
    if text.replace(" ", "") == "[]":
        return ()
    items = [item.strip() for item in text.strip().removeprefix("[").removesuffix("]").split(",")]
    if not all(item.isascii() and item.isdecimal() for item in items):
        raise argparse.ArgumentTypeError(
            f"expected camera ids separated by commas, e.g. 0,10, got {text!r}"
        )
    return tuple(int(item) for item in items)


def path_argument(value: str) -> Path:
    """argparse type of a path: any non-blank text (an empty one would silently mean the
    current folder, where an output option writes, and replaces, files)."""
    if not value.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {value!r}")
    return Path(value)


def writable_file(value: str) -> Path:
    """argparse type of an output file option: a path that can be written once the command's
    work is done, checked before it starts (so minutes of work are not lost to a bad path)."""
    path = path_argument(value).expanduser().absolute()
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder, expected a file path")
    try:
        require_creatable_folder(path.parent, f"cannot write {path}")
    except InputError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return path


def run_tool(main: Callable[[], int]) -> int:
    """Run a tool's `main` and return its exit status; output piped into a reader that stopped
    early (`artifacts ls | head`) ends it with BROKEN_PIPE_EXIT instead of a traceback."""
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
