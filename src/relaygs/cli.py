"""Command-line plumbing the relaygs tools share: usage errors as one line, checked counts."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import NoReturn


class OneLineErrorParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are a single stderr line (exit status 2), without
    argparse's usage block; its sub-command parsers are of the same class (argparse's default)."""

    def error(self, message: str) -> NoReturn:
        """Print `error: message` with where to find help, and exit 2."""
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def int_at_least(minimum: int) -> Callable[[str], int]:
    """argparse type of an integer option that must be >= `minimum`: a smaller value is refused
    in one line rather than silently clamped."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return value

    return parse
