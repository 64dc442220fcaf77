"""Exceptions that carry a one-line, user-facing message."""


class RelayGSError(Exception):
    """Base class for errors relaygs reports to the user as a single line."""


class InputError(RelayGSError, ValueError):
    """Bad user input: a file, field or value that is not what was expected."""


class DivergenceError(RelayGSError, FloatingPointError):
    """A training run produced a non-finite value; names the stage, step and tensor."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during training; the message names the stage, the step and what a rerun resumes
    from. A KeyboardInterrupt, so code that handles Ctrl-C still sees one."""
