"""`refused`: the one check a bad-input test makes of a refusal, by type and what it names."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest


@contextmanager
def refused(error: type[BaseException], *named: str) -> Iterator[pytest.ExceptionInfo]:
    """Expect `error` whose message is one line naming each of `named` (a key, a file, a
    value), whatever its wording."""
    with pytest.raises(error) as caught:
        yield caught
    message = str(caught.value)
    assert "\n" not in message, message
    missing = [name for name in named if name not in message]
    assert not missing, f"{message!r} does not name {missing}"
