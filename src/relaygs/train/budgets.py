"""Named step budgets, read from `conf/budget/*.yaml` so the numbers are written once.

`paper` leaves the stage defaults (3000 / 14000 / 20000 steps). `small` runs the default
pipeline on the default synthetic scene (160×90, 64 frames) in under a quarter of an hour on
a 2-core CPU. `smoke` is a few steps of every code path for tests. Each budget maps a
section name (`train`, a stage type, ...) to the overrides the app merges over it; the
budget's own `budget:` block (name, multiplier) and run-level keys stay with the app.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

from omegaconf import OmegaConf

from relaygs.errors import InputError
from relaygs.paths import config_dir

RUN_KEYS = ("budget", "threads", "tensorboard")
"""Keys of a budget file that the app applies to the run, not to a stage's config."""


def load_budget(name: str, sections: Collection[str]) -> dict[str, dict[str, Any]]:
    """The section overrides of `conf/budget/<name>.yaml`; a key that is neither one of
    `sections` (`train`, `eval` and the stage types) nor in RUN_KEYS is refused, as it would
    otherwise be dropped without a word."""
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
