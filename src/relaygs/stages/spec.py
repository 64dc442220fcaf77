"""`StageSpec`: everything the app needs to know of one stage type, declared by its module."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.pipeline.dag import StageFn
from relaygs.train.canonical import SectionCanonical


class StageSettings(Protocol):
    """A stage's settings dataclass (Hydra structured config) with its range checks."""

    @classmethod
    def from_config(cls, data: Mapping[str, Any] | None) -> Any: ...

    def validate(self) -> None: ...


@dataclass(frozen=True)
class StageSpec:
    """One stage type: name (config section, artifact label), function, settings, schema version
    (bumped when what it computes changes), accepted upstream types, canonical settings form."""

    name: str
    run: StageFn
    settings: type[StageSettings]
    schema_version: int
    upstream: tuple[str, ...] = ()
    canonical: SectionCanonical | None = None

    def __post_init__(self) -> None:
        """A schema version that is no integer >= 1 would key artifacts ambiguously."""
        version = self.schema_version
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise InputError(
                f"stage type {self.name!r}: schema_version must be an integer >= 1, got {version!r}"
            )

    def canonical_section(self, section: Mapping[str, Any], scene: Scene) -> dict[str, Any]:
        """`section` in its canonical form on `scene` (unchanged for a stage without one)."""
        return dict(section) if self.canonical is None else self.canonical(section, scene)
