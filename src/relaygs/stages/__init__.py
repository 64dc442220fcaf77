"""The method's stages as plain functions `(scene, upstream artifacts, cfg) -> Artifact`.

`STAGES` maps each stage type to its function, `CONFIGS` to its settings dataclass (whose
`from_config` validates a section), `SCHEMA_VERSIONS` to its artifact schema version,
`UPSTREAM` to the stage types its upstream node may have, and `CANONICAL` (where a stage has
one) to the canonical form of its section, which `canonical_config` applies before a config
is keyed and run.
`evaluate` scores a final artifact on the test views; `render_model` renders any artifact.
Live metrics go through `relaygs.stages.log` sinks.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import decouple as _decouple
from relaygs.stages import deform as _deform
from relaygs.stages import relay as _relay
from relaygs.stages import replicate as _replicate
from relaygs.stages import warmup as _warmup
from relaygs.stages.budgets import BUDGETS
from relaygs.stages.canonical import SectionCanonical, one_segment_at_most
from relaygs.stages.evaluate import EvalSettings, evaluate
from relaygs.stages.model_render import ModelRenderer, render_model
from relaygs.stages.scene_model import SceneModel
from relaygs.stages.train_settings import TrainSettings

StageFn = Callable[[Scene, dict[str, Artifact], dict], Artifact]

STAGES: dict[str, StageFn] = {
    "decouple": _decouple.decouple,
    "relay": _relay.relay,
    "deform": _deform.deform,
    "warmup": _warmup.warmup,
    "replicate": _replicate.replicate,
}

CONFIGS: dict[str, Any] = {
    "decouple": _decouple.DecoupleConfig,
    "relay": _relay.RelayConfig,
    "deform": _deform.DeformConfig,
    "warmup": _warmup.WarmupConfig,
    "replicate": _replicate.ReplicateConfig,
}

SCHEMA_VERSIONS: dict[str, int] = {
    "decouple": _decouple.SCHEMA_VERSION,
    "relay": _relay.SCHEMA_VERSION,
    "deform": _deform.SCHEMA_VERSION,
    "warmup": _warmup.SCHEMA_VERSION,
    "replicate": _replicate.SCHEMA_VERSION,
}

UPSTREAM: dict[str, tuple[str, ...]] = {
    "decouple": (),
    "relay": _relay.ACCEPTED_UPSTREAM,
    "deform": _deform.ACCEPTED_UPSTREAM,
    "warmup": (),
    "replicate": _replicate.ACCEPTED_UPSTREAM,
}
"""The stage types of the one upstream node each stage type reads (empty: none, it starts
from the scene); pipelines are checked against it before any stage runs."""

CANONICAL: dict[str, SectionCanonical] = {
    "relay": one_segment_at_most,
    "replicate": one_segment_at_most,
}


def canonical_config(stage: str, cfg: Mapping[str, Any], scene: Scene) -> dict[str, Any]:
    """`cfg` with stage type `stage`'s section in its canonical form on `scene` (`CANONICAL`;
    unchanged for a stage without one): what the stage's artifact key hashes and it runs with."""
    canonical = dict(cfg)
    if stage in CANONICAL and isinstance(cfg.get(stage), Mapping):
        canonical[stage] = CANONICAL[stage](cfg[stage], scene)
    return canonical


def validate_config(stage: str, cfg: Mapping[str, Any]) -> None:
    """Raise InputError (one line naming the key) unless `cfg` is valid for stage type `stage`:
    its own section, the shared `train` section and, when present, `eval`."""
    if stage not in CONFIGS and stage not in STAGES:
        raise InputError(f"unknown stage type {stage!r}; expected one of {sorted(CONFIGS)}")
    require_registered(stage)
    CONFIGS[stage].from_config(cfg.get(stage))
    TrainSettings.from_config(cfg.get("train"))
    EvalSettings.from_config(cfg.get("eval"))


REGISTRIES: dict[str, Mapping[str, Any]] = {
    "STAGES": STAGES,
    "CONFIGS": CONFIGS,
    "SCHEMA_VERSIONS": SCHEMA_VERSIONS,
    "UPSTREAM": UPSTREAM,
}
"""The registries every stage type must be in (CANONICAL is optional)."""


def require_registered(stage: str) -> None:
    """Raise InputError unless stage type `stage` is in every one of REGISTRIES: one missing
    from SCHEMA_VERSIONS would be keyed as version 1 and reuse stale artifacts, one missing
    from UPSTREAM would have its pipelines' upstream unchecked until the stage ran."""
    missing = [name for name, registry in REGISTRIES.items() if stage not in registry]
    if missing:
        raise InputError(
            f"stage type {stage!r} is not registered in {' and '.join(missing)} of "
            "src/relaygs/stages/__init__.py (see docs/extending.md)"
        )


def require_complete_registries() -> None:
    """Raise InputError unless every stage type of any registry is in all of them with a
    schema version that is an integer >= 1: checked when a run loads the stages, before any
    config or pipeline is read."""
    for stage in sorted(set().union(*REGISTRIES.values())):
        require_registered(stage)
        version = SCHEMA_VERSIONS[stage]
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise InputError(
                f"stage type {stage!r}: its SCHEMA_VERSION must be an integer >= 1, got "
                f"{version!r} (src/relaygs/stages/__init__.py, SCHEMA_VERSIONS)"
            )


__all__ = [
    "BUDGETS",
    "CANONICAL",
    "CONFIGS",
    "REGISTRIES",
    "SCHEMA_VERSIONS",
    "STAGES",
    "UPSTREAM",
    "EvalSettings",
    "ModelRenderer",
    "SceneModel",
    "StageFn",
    "TrainSettings",
    "canonical_config",
    "evaluate",
    "render_model",
    "require_complete_registries",
    "require_registered",
    "validate_config",
]
