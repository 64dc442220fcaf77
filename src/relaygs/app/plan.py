"""Validate a resolved run config and derive every node's stage config before any work starts.

A stage receives `{"seed": ..., "train": <train section>, "<stage type>": <its section>}`: the
section is the config group's values with the pipeline node's `overrides` merged over them and
the budget multiplier applied to its step counts. Nothing else reaches a stage (or its key).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from relaygs.app.scenes import SceneSpec, scene_spec
from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder
from relaygs.pipeline import Node, Pipeline, load_pipeline
from relaygs.pipeline.store import ON_CORRUPT_CHOICES

StageValidator = Callable[[str, Mapping[str, Any]], None]
"""Checks the config a stage type receives (its section, `train`, and `eval` when present);
raises a one-line InputError naming the bad key."""


@dataclass(frozen=True)
class RunPlan:
    """Everything a run needs, validated: the pipeline, each node's stage config, the scene.

    `stage_types` are all implemented stage types, whether or not this pipeline runs them."""

    pipeline: Pipeline
    stage_types: frozenset[str]
    node_configs: dict[str, dict[str, Any]]
    scene: SceneSpec
    seed: int
    on_corrupt: str
    artifacts_root: Path
    scenes_dir: Path
    eval_config: dict[str, Any]
    preview_frames: int
    threads: int | None = None

    @property
    def device(self) -> str:
        """`train.device`, where every stage trains and the evaluation renders."""
        return str(self.eval_config["train"].get("device", "cpu"))

    @property
    def progress(self) -> bool:
        """Whether progress bars are shown (`train.progress`, on unless set false)."""
        return bool(self.eval_config["train"].get("progress", True))

    def config_for(self, node: Node) -> dict[str, Any]:
        """The stage config node `node` runs with (what `run_pipeline` asks for)."""
        return self.node_configs[node.name]


def plan_run(
    cfg: Mapping[str, Any], stage_types: Collection[str], validate: StageValidator
) -> RunPlan:
    """Check the whole config (paths already absolute) and build the plan; bad input raises
    one-line InputErrors naming the field. `stage_types` are the implemented stage types;
    `validate` checks each node's stage config (the output node's with `eval` added)."""
    seed = cfg.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError(f"seed must be an integer >= 0, got {seed!r}")
    artifacts = cfg["artifacts"]
    if artifacts.get("on_corrupt") not in ON_CORRUPT_CHOICES:
        raise InputError(
            f"artifacts.on_corrupt must be one of {list(ON_CORRUPT_CHOICES)}, "
            f"got {artifacts.get('on_corrupt')!r}"
        )
    threads = cfg.get("threads")
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, int) or threads < 1
    ):
        raise InputError(f"threads must be an integer >= 1 or null, got {threads!r}")
    pipeline = load_pipeline(str(cfg["pipeline"]["name"]), known_stages=stage_types)
    multiplier, scaled_keys = _budget(cfg.get("budget") or {})
    eval_config = {"seed": seed, "train": _section(cfg, "train"), "eval": _section(cfg, "eval")}
    for what, path in (
        ("paths.outputs", cfg["paths"]["outputs"]),
        ("paths.scenes", cfg["paths"]["scenes"]),
        ("artifacts.root", artifacts["root"]),
    ):
        require_creatable_folder(Path(path), what)
    node_configs = {}
    for node in pipeline.topological_order():
        section = cfg.get(node.stage)
        if not isinstance(section, Mapping):
            raise InputError(f"config has no '{node.stage}' section for node {node.name!r}")
        where = f"{pipeline.path}: node {node.name!r} overrides"
        merged = merge_overrides(dict(section), node.overrides, where)
        scaled = scale_steps(merged, multiplier, scaled_keys)
        node_configs[node.name] = {
            "seed": seed,
            "train": copy.deepcopy(eval_config["train"]),
            node.stage: scaled,
        }
        evaluated = node is pipeline.output_node
        validate(node.stage, {**node_configs[node.name], **(eval_config if evaluated else {})})
    return RunPlan(
        pipeline=pipeline,
        stage_types=frozenset(stage_types),
        node_configs=node_configs,
        scene=scene_spec(cfg["scene"]),
        seed=seed,
        on_corrupt=artifacts["on_corrupt"],
        artifacts_root=Path(artifacts["root"]),
        scenes_dir=Path(cfg["paths"]["scenes"]),
        eval_config=eval_config,
        preview_frames=_preview_frames(cfg),
        threads=threads,
    )


def merge_overrides(
    section: Mapping[str, Any], overrides: Mapping[str, Any], where: str
) -> dict[str, Any]:
    """A deep copy of `section` with `overrides` merged in; an override of a key the section
    lacks is an InputError (a typo would otherwise be silently ignored)."""
    merged = copy.deepcopy(dict(section))
    for key, value in overrides.items():
        if key not in merged:
            raise InputError(f"{where}: unknown setting {key!r} (known: {', '.join(merged)})")
        if isinstance(value, Mapping) and isinstance(merged[key], Mapping):
            merged[key] = merge_overrides(merged[key], value, f"{where}.{key}")
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def scale_steps(
    section: Mapping[str, Any], multiplier: float, keys: Collection[str]
) -> dict[str, Any]:
    """`section` with every positive integer entry whose name is in `keys` (at any depth)
    times `multiplier`, rounded and kept >= 1; zeros (often "off"), negatives (left for
    validation) and everything else are unchanged."""
    scaled: dict[str, Any] = {}
    for key, value in section.items():
        if isinstance(value, Mapping):
            scaled[key] = scale_steps(value, multiplier, keys)
        elif key in keys and isinstance(value, int) and not isinstance(value, bool) and value > 0:
            scaled[key] = max(1, round(value * multiplier))
        else:
            scaled[key] = copy.deepcopy(value)
    return scaled


def _section(cfg: Mapping[str, Any], name: str) -> dict[str, Any]:
    """A copy of the config section `name`, which must be a mapping."""
    section = cfg.get(name)
    if not isinstance(section, Mapping):
        raise InputError(f"{name}: expected a config section (a mapping), got {section!r}")
    return dict(section)


def _preview_frames(cfg: Mapping[str, Any]) -> int:
    """`tensorboard.preview_frames`: how many render-vs-truth frames TensorBoard gets (>= 0)."""
    section = _section(cfg, "tensorboard")
    unknown = sorted(set(section) - {"preview_frames"})
    if unknown:
        raise InputError(f"tensorboard: unknown setting(s) {unknown}; expected ['preview_frames']")
    count = section.get("preview_frames")
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise InputError(f"tensorboard.preview_frames must be an integer >= 0, got {count!r}")
    return count


def _budget(budget: Mapping[str, Any]) -> tuple[float, list[str]]:
    """The budget's step multiplier (a finite number > 0) and the keys it scales."""
    multiplier = budget.get("multiplier", 1.0)
    if (
        isinstance(multiplier, bool)
        or not isinstance(multiplier, int | float)
        or not math.isfinite(multiplier)
        or multiplier <= 0
    ):
        raise InputError(f"budget.multiplier must be a number > 0, got {multiplier!r}")
    keys = budget.get("scaled_keys", ["steps"])
    if not isinstance(keys, list) or not all(isinstance(key, str) for key in keys):
        raise InputError(f"budget.scaled_keys must be a list of setting names, got {keys!r}")
    return float(multiplier), keys
