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

from relaygs.paths import config_dir

SECTIONS = ("train", "eval", "decouple", "warmup", "relay", "replicate", "deform")


def load_budget(name: str) -> dict[str, dict[str, Any]]:
    """The section overrides of `conf/budget/<name>.yaml`."""
    raw = OmegaConf.to_container(OmegaConf.load(config_dir() / "budget" / f"{name}.yaml"))
    return {key: value for key, value in raw.items() if key in SECTIONS}


BUDGETS: dict[str, dict[str, dict[str, Any]]] = {
    path.stem: load_budget(path.stem) for path in sorted((config_dir() / "budget").glob("*.yaml"))
}
