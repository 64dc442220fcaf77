"""Named step budgets (`paper`, `medium`, `small`, `smoke`): section overrides from
`conf/budget/`, a budget over the ones its defaults list names."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from relaygs.errors import InputError
from relaygs.paths import config_dir

RUN_KEYS = ("budget", "threads", "tensorboard")  # keys the app applies to the run, not a stage
SELF = "_self_"  # a defaults list's place for the file's own keys


def load_budget(name: str, sections: Collection[str]) -> dict[str, dict[str, Any]]:
    """Section overrides of `conf/budget/<name>.yaml`; keys neither sections nor RUN_KEYS fail."""
    path = config_dir() / "budget" / f"{name}.yaml"
    raw = OmegaConf.to_container(_composed(path))
    unknown = sorted(set(raw) - set(sections) - set(RUN_KEYS))
    if unknown:
        raise InputError(
            f"{path}: section(s) {unknown} are no stage type nor run key; "
            f"expected some of {[*sections, *RUN_KEYS]}"
        )
    return {key: value for key, value in raw.items() if key in sections}


def _composed(path: Path) -> DictConfig:
    """A budget file over the budgets its defaults list names, as Hydra composes it: each named
    budget in order, then the file's own keys (`_self_`, which must come last)."""
    own = OmegaConf.load(path)
    bases = list(own.pop("defaults", []))
    if bases and bases[-1] == SELF:
        bases.pop()
    if not all(isinstance(base, str) and base != SELF for base in bases):
        raise InputError(
            f"{path}: defaults: expected budget names, then `{SELF}` last; got {bases}"
        )
    return OmegaConf.merge(*(_composed(path.parent / f"{base}.yaml") for base in bases), own)


def load_budgets(sections: Collection[str]) -> dict[str, dict[str, dict[str, Any]]]:
    """Every budget of `conf/budget/` by name (`load_budget`)."""
    folder = config_dir() / "budget"
    return {path.stem: load_budget(path.stem, sections) for path in sorted(folder.glob("*.yaml"))}
