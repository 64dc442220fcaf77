"""The build in progress, visible to stage code so it can write in-stage checkpoints.

`ArtifactStore.get_or_build` sets it around the build call; stage functions keep their
`(scene, upstream, cfg)` signature and ask `current_build()` where to checkpoint.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

from relaygs.pipeline.checkpoint import StageCheckpointer


@dataclass
class BuildContext:
    """Which artifact is being built, and in which store; `earlier_seconds` is the work done
    before the checkpoint the build resumed from (0 for a fresh build), which the artifact's
    build time includes."""

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
