"""Named step budgets, read from `conf/budget/*.yaml` so the numbers are written once.

`paper` leaves the stage defaults (3000 / 14000 / 20000 steps). `small` runs the default
pipeline on the default synthetic scene (160×90, 64 frames) in under a quarter of an hour on
a 2-core CPU. `smoke` is a few steps of every code path for tests. Each budget maps a
section name (`train`, a stage type, ...) to the overrides the app merges over it; the
budget's own `budget:` block (name, multiplier) and run-level keys stay with the app.
"""

from __future__ import annotations

from typing import Any

from omegaconf import OmegaConf

from relaygs.errors import InputError
from relaygs.paths import config_dir

SECTIONS = ("train", "eval", "decouple", "warmup", "relay", "replicate", "deform")
RUN_KEYS = ("budget", "threads", "tensorboard")
"""Keys of a budget file that the app applies to the run, not to a stage's config."""


def load_budget(name: str) -> dict[str, dict[str, Any]]:
    """The section overrides of `conf/budget/<name>.yaml`; a key that is neither in SECTIONS
    nor in RUN_KEYS (a new stage's section not added to SECTIONS) is refused, as it would be
    missing from BUDGETS and tests would train that stage at its paper step counts."""
    path = config_dir() / "budget" / f"{name}.yaml"
    raw = OmegaConf.to_container(OmegaConf.load(path))
    unknown = sorted(set(raw) - set(SECTIONS) - set(RUN_KEYS))
    if unknown:
        raise InputError(
            f"{path}: section(s) {unknown} not in SECTIONS of relaygs/stages/budgets.py; "
            f"expected some of {[*SECTIONS, *RUN_KEYS]}"
        )
    return {key: value for key, value in raw.items() if key in SECTIONS}


BUDGETS: dict[str, dict[str, dict[str, Any]]] = {
    path.stem: load_budget(path.stem) for path in sorted((config_dir() / "budget").glob("*.yaml"))
}
