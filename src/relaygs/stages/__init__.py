"""The method's stages, each declared by its module's `SPEC`; `SPECS` lists them by type."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.stages import decouple, deform, relay, replicate, warmup
from relaygs.stages.config import register_schemas
from relaygs.stages.evaluate import EvalSettings, evaluate
from relaygs.stages.spec import StageSpec
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.budgets import load_budgets
from relaygs.train.model_render import ModelRenderer, render_model
from relaygs.train.scene_model import SceneModel

SPECS: dict[str, StageSpec] = {
    spec.name: spec
    for spec in (decouple.SPEC, relay.SPEC, deform.SPEC, warmup.SPEC, replicate.SPEC)
}
register_schemas({"train": TrainSettings, **{name: spec.settings for name, spec in SPECS.items()}})


@functools.cache
def step_budgets() -> dict[str, dict[str, dict[str, Any]]]:
    """The named step budgets of `conf/budget/`, read on first use (importing reads no file)."""
    return load_budgets(("train", "eval", *SPECS))


def canonical_config(stage: str, cfg: Mapping[str, Any], scene: Scene) -> dict[str, Any]:
    """`cfg` with `stage`'s section in its canonical form on `scene` (keyed and run with)."""
    canonical = dict(cfg)
    if isinstance(cfg.get(stage), Mapping):
        canonical[stage] = SPECS[stage].canonical_section(cfg[stage], scene)
    return canonical


def validate_config(stage: str, cfg: Mapping[str, Any]) -> None:
    """InputError naming the key unless `cfg` fits stage type `stage` (with `train`, `eval`)."""
    if stage not in SPECS:
        raise InputError(f"unknown stage type {stage!r}; expected one of {sorted(SPECS)}")
    SPECS[stage].settings.from_config(cfg.get(stage)).validate()
    TrainSettings.from_config(cfg.get("train")).validate()
    EvalSettings.from_config(cfg.get("eval"))


__all__ = [
    "SPECS",
    "EvalSettings",
    "ModelRenderer",
    "SceneModel",
    "StageSpec",
    "TrainSettings",
    "canonical_config",
    "evaluate",
    "render_model",
    "step_budgets",
    "validate_config",
]
