"""Exceptions that carry a one-line, user-facing message."""

from __future__ import annotations


class RelayGSError(Exception):
    """Base class for errors relaygs reports to the user as a single line."""


class InputError(RelayGSError, ValueError):
    """Bad user input: a file, field or value that is not what was expected."""


class DivergenceError(RelayGSError, FloatingPointError):
    """A training run produced a non-finite value; names the stage, step and tensor."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during training; the message names the stage, the step and what a rerun resumes
    from. A KeyboardInterrupt, so code that handles Ctrl-C still sees one."""


def one_line(error: BaseException) -> str:
    """An exception's message folded into one line (Hydra's and OmegaConf's span several; their
    "See https://..." and "full_key:" detail lines are dropped)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return " ".join(line for line in lines if not line.startswith(_DETAIL_PREFIXES))


_DETAIL_PREFIXES = ("See https://", "full_key:", "object_type=")
