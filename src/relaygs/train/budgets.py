"""Named step budgets (`paper`, `small`, `smoke`): section overrides from `conf/budget/`."""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

from omegaconf import OmegaConf

from relaygs.errors import InputError
from relaygs.paths import config_dir

RUN_KEYS = ("budget", "threads", "tensorboard")  # keys the app applies to the run, not a stage


def load_budget(name: str, sections: Collection[str]) -> dict[str, dict[str, Any]]:
    """Section overrides of `conf/budget/<name>.yaml`; keys neither sections nor RUN_KEYS fail."""
    path = config_dir() / "budget" / f"{name}.yaml"
    raw = OmegaConf.to_container(OmegaConf.load(path))
    unknown = sorted(set(raw) - set(sections) - set(RUN_KEYS))
    if unknown:
        raise InputError(
            f"{path}: section(s) {unknown} are no stage type nor run key; "
            f"expected some of {[*sections, *RUN_KEYS]}"
        )
    return {key: value for key, value in raw.items() if key in sections}


def load_budgets(sections: Collection[str]) -> dict[str, dict[str, dict[str, Any]]]:
    """Every budget of `conf/budget/` by name (`load_budget`)."""
    folder = config_dir() / "budget"
    return {path.stem: load_budget(path.stem, sections) for path in sorted(folder.glob("*.yaml"))}
