"""The build in progress (set by `ArtifactStore.get_or_build`), so stage code can ask
`current_build()` where to write in-stage checkpoints."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

from relaygs.pipeline.checkpoint import StageCheckpointer


@dataclass
class BuildContext:
    """Which artifact is being built, in which store; `earlier_seconds`, the work before the
    checkpoint it resumed from, counts in its build time."""

    store_root: Path
    stage: str
    key: str
    earlier_seconds: float = 0.0

    def checkpointer(self, every_n_steps: int) -> StageCheckpointer:
        """In-stage checkpointer for this build, saving every `every_n_steps` steps."""
        return StageCheckpointer(self.store_root, self.stage, self.key, every_n_steps)


_CURRENT: ContextVar[BuildContext | None] = ContextVar("relaygs_current_build", default=None)


def current_build() -> BuildContext | None:
    """The build running in this context, or None outside `ArtifactStore.get_or_build`."""
    return _CURRENT.get()


@contextmanager
def building(context: BuildContext) -> Iterator[BuildContext]:
    """Make `context` the current build for the duration of the `with` block."""
    token = _CURRENT.set(context)
    try:
        yield context
    finally:
        _CURRENT.reset(token)
