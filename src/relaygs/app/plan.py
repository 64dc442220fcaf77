"""Validate a resolved run config and derive every node's stage config before any work starts.

A stage receives `{"seed": ..., "train": <train section>, "<stage type>": <its section>}`: the
section is the config group's values with the pipeline node's `overrides` merged over them and
the budget multiplier applied to its step counts. Nothing else reaches a stage (or its key).
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from relaygs.app.scenes import SceneSpec, scene_spec
from relaygs.data.options import require_int
from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder
from relaygs.pipeline import Node, Pipeline, load_pipeline
from relaygs.pipeline.spec import names_a_file, parse_pipeline
from relaygs.pipeline.store import ON_CORRUPT_CHOICES
from relaygs.splat import BACKENDS

HPARAMS_CHOICES = ("swept", "all")
"""`tensorboard.hparams`: the HParams entry holds the settings the sweep varies (with the
pipeline and variant), or the whole config besides."""

SECTION_KEYS = {
    "tensorboard": ("preview_frames", "hparams"),
    "report": ("reference",),
    "paths": ("outputs", "scenes"),
    "artifacts": ("root", "on_corrupt"),
    "pipeline": ("name", "description", "nodes"),
    "budget": ("name", "multiplier", "scaled_keys"),
    "splat": ("backend",),
}
"""The settings of the config sections that are not a stage's (stage sections, `train`,
`eval` and `scene` are checked by their own parsers): a `+budget.multipler=2` is refused."""
TOP_LEVEL_KEYS = frozenset(
    {"seed", "variant", "experiment_name", "threads", "train", "eval", "scene", *SECTION_KEYS}
)
"""Top-level keys of a run config besides one section per stage type."""
MAX_THREADS = 1024
"""Most torch CPU threads a job may ask for: more fails in the OpenMP runtime at job start
(16384 could not be created here, 100000 crashed the process), after the scene is ready."""
CONFIG_GROUPS = ("pipeline", "budget")
"""Config groups whose section a run reads here: a value there was meant to choose a file."""
LABELS = ("variant", "experiment_name", "report.reference", "scene.name", "budget.name")
"""Settings that only label a run in its result (null allowed but for `variant`)."""

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
    splat_backend: str = "auto"
    hparams: str = "swept"

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
    cfg: Mapping[str, Any],
    stage_types: Collection[str],
    validate: StageValidator,
    accepted_upstream: Mapping[str, Collection[str]] | None = None,
) -> RunPlan:
    """Check the whole config (paths already absolute) and build the plan; bad input raises
    one-line InputErrors naming the field. `stage_types` are the implemented stage types;
    `validate` checks each node's stage config (the output node's with `eval` added);
    `accepted_upstream` the pipeline's upstream node types (`load_pipeline`)."""
    _check_setting_names(cfg, stage_types)
    seed = require_int("seed", cfg.get("seed"), minimum=0, prefix="")
    artifacts, paths = _section(cfg, "artifacts"), _section(cfg, "paths")
    if artifacts.get("on_corrupt") not in ON_CORRUPT_CHOICES:
        raise InputError(
            f"artifacts.on_corrupt must be one of {list(ON_CORRUPT_CHOICES)}, "
            f"got {artifacts.get('on_corrupt')!r}"
        )
    threads = cfg.get("threads")
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS
    ):
        raise InputError(
            f"threads must be an integer in [1, {MAX_THREADS}] or null, got {threads!r}"
        )
    splat_backend = (_section(cfg, "splat") if "splat" in cfg else {}).get("backend", "auto")
    if splat_backend not in BACKENDS:
        raise InputError(f"splat.backend must be one of {list(BACKENDS)}, got {splat_backend!r}")
    pipeline = _pipeline(cfg, stage_types, accepted_upstream)
    for dotted in LABELS:  # after the pipeline: `variant` is `${pipeline.name}` by default
        _require_label(cfg, dotted)
    multiplier, scaled_keys = _budget(_section(cfg, "budget") if "budget" in cfg else {})
    _require_stage_setting_names(cfg, stage_types, scaled_keys)
    eval_config = {"seed": seed, "train": _section(cfg, "train"), "eval": _section(cfg, "eval")}
    for what, path in (
        ("paths.outputs", paths["outputs"]),
        ("paths.scenes", paths["scenes"]),
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
        try:
            validate(node.stage, {**node_configs[node.name], **(eval_config if evaluated else {})})
        except InputError as error:
            raise InputError(f"{error}{_pinned_by(node, str(error), where)}") from error
    return RunPlan(
        pipeline=pipeline,
        stage_types=frozenset(stage_types),
        node_configs=node_configs,
        scene=scene_spec(_section(cfg, "scene")),
        seed=seed,
        on_corrupt=artifacts["on_corrupt"],
        artifacts_root=Path(artifacts["root"]),
        scenes_dir=Path(paths["scenes"]),
        eval_config=eval_config,
        preview_frames=_preview_frames(cfg),
        threads=threads,
        splat_backend=splat_backend,
        hparams=_hparams_choice(cfg),
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


def _pinned_by(node: Node, message: str, where: str) -> str:
    """` (set by <where>)` when `message` is about a setting that the pipeline node pins in its
    `overrides` (e.g. `deform.gamma: ...`), whose value the command line cannot change; else
    empty."""
    pinned = [f"{node.stage}.{key}" for key in _dotted_keys(node.overrides)]
    if any(re.match(rf"{re.escape(key)}\b", message) for key in pinned):
        return f" (set by {where})"
    return ""


def _dotted_keys(section: Mapping[str, Any]) -> list[str]:
    """The dotted paths of every leaf of a nested mapping."""
    keys = []
    for key, value in section.items():
        if isinstance(value, Mapping) and value:
            keys += [f"{key}.{inner}" for inner in _dotted_keys(value)]
        else:
            keys.append(str(key))
    return keys


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
            product = value * multiplier
            if not math.isfinite(product):  # 1e307 × 20 steps: round() would raise
                raise InputError(
                    f"budget.multiplier must keep every step count finite, got {multiplier!r} "
                    f"({key}: {value} times {multiplier!r} overflows)"
                )
            scaled[key] = max(1, round(product))
        else:
            scaled[key] = copy.deepcopy(value)
    return scaled


def _section(cfg: Mapping[str, Any], name: str) -> dict[str, Any]:
    """A copy of the config section `name`, which must be a mapping."""
    section = cfg.get(name)
    if not isinstance(section, Mapping):
        if name in CONFIG_GROUPS:  # `pipeline: 4dgs` in an experiment file
            raise InputError(group_value_error(name, section))
        raise InputError(f"{name}: expected a config section (a mapping), got {section!r}")
    return dict(section)


def group_value_error(group: str, value: Any) -> str:
    """The line for a config group that holds a value, not a section: `pipeline: 4dgs` in an
    experiment file replaces the group's settings with that text instead of choosing its file."""
    name = value if isinstance(value, str) and value else "NAME"
    return (
        f"{group}: expected a config section (a mapping), got {value!r}: {group} is a config "
        f"group, choose its file with {group}={name} on the command line, or in an experiment "
        f"file with `defaults: [override /{group}: {name}]`"
    )


def _pipeline(
    cfg: Mapping[str, Any],
    stage_types: Collection[str],
    accepted_upstream: Mapping[str, Collection[str]] | None,
) -> Pipeline:
    """The pipeline `pipeline.name` names (a file of conf/pipeline/, or a file's path). Nodes
    are changed in that file: a composed section whose nodes differ from it (`pipeline.name`
    changed alone, or a node changed on the command line) is refused."""
    section = _section(cfg, "pipeline")
    name = section.get("name")
    if isinstance(name, bool) or not isinstance(name, str | int) or name == "":
        raise InputError(
            f"pipeline.name: expected the name of a conf/pipeline/<name>.yaml or a pipeline "
            f"file's path, got {name!r} (each conf/pipeline/<name>.yaml holds `name: <name>`)"
        )
    declared = load_pipeline(str(name), stage_types, accepted_upstream)
    if names_a_file(str(name)) or parse_pipeline(section, declared.path) == declared:
        return declared
    raise InputError(
        f"pipeline: the config's nodes differ from those of {declared.path}: choose a "
        f"pipeline with pipeline=<name>, and change its nodes in its file"
    )


def _check_setting_names(cfg: Mapping[str, Any], stage_types: Collection[str]) -> None:
    """No top-level setting but TOP_LEVEL_KEYS and the stage sections, and none in a section
    of SECTION_KEYS but its own."""
    if isinstance(cfg.get("experiment"), Mapping):
        raise InputError(
            f"top level: unknown setting 'experiment' (holding {sorted(cfg['experiment'])}): "
            "an experiment file in conf/experiment/ must start with the line "
            "`# @package _global_`, else its settings land under `experiment.`"
        )
    if isinstance(cfg.get("_global"), Mapping):  # `# @package _global`, one underscore short
        raise InputError(
            f"top level: unknown setting '_global' (holding {sorted(cfg['_global'])}): an "
            "experiment file's first line must be `# @package _global_`, with the trailing "
            "underscore"
        )
    _require_known_keys(cfg, "top level", TOP_LEVEL_KEYS | set(stage_types))
    for name, keys in SECTION_KEYS.items():
        if name in cfg:  # a missing section is reported where it is read
            _require_known_keys(_section(cfg, name), name, keys)


def _require_known_keys(section: Mapping[str, Any], name: str, known: Collection[str]) -> None:
    """Refuse settings of `section` (called `name`) outside `known`: a typo added with `+`
    (`+budget.multipler=2`) would otherwise be ignored without a word."""
    unknown = sorted(set(section) - set(known))
    if unknown:
        raise InputError(f"{name}: unknown setting(s) {unknown}; expected {sorted(known)}")


def _require_stage_setting_names(
    cfg: Mapping[str, Any], stage_types: Collection[str], scaled_keys: Collection[str]
) -> None:
    """Each of `budget.scaled_keys` names a setting of some stage section, at any depth: a
    misspelt name (`stpes`) would leave the step counts it meant unscaled without a word."""
    names: set[str] = set()
    for stage in stage_types:
        if isinstance(cfg.get(stage), Mapping):
            names |= _setting_names(cfg[stage])
    unknown = sorted(set(scaled_keys) - names)
    if unknown:
        raise InputError(
            f"budget.scaled_keys: {unknown} name no setting of any stage section "
            "(expected step-count settings such as 'steps' or 'densify_every')"
        )


def _setting_names(section: Mapping[str, Any]) -> set[str]:
    """Every key of `section` and of the mappings nested in it."""
    names = set(section)
    for value in section.values():
        if isinstance(value, Mapping):
            names |= _setting_names(value)
    return names


def _require_label(cfg: Mapping[str, Any], dotted: str) -> None:
    """A label setting (LABELS) is a string, a finite number or, but for `variant`, null: a
    list or mapping would make `result.json` one that the sweep report refuses, and NaN one
    that cannot be written, both only once the job has trained. A variant, which names a sweep
    job's folder, holds no path separator (its folder would land elsewhere)."""
    section, _, key = dotted.rpartition(".")
    values = cfg.get(section) if section else cfg
    if not isinstance(values, Mapping) or key not in values:
        return  # a missing section is reported where it is read
    value = values[key]
    number = isinstance(value, int | float) and math.isfinite(value)
    nullable = value is None and dotted != "variant"
    if not (isinstance(value, str) or number or nullable):
        kind = "a string or a number" if dotted == "variant" else "a string, a number or null"
        raise InputError(f"{dotted}: expected {kind}, got {value!r}")
    if dotted == "variant" and any(separator in str(value) for separator in ("/", "\\")):
        raise InputError(
            f"variant: {value!r} holds a path separator; a sweep names each job's folder "
            "<job>_<variant> inside the sweep folder, so a variant is a plain name (no / or \\)"
        )


def _preview_frames(cfg: Mapping[str, Any]) -> int:
    """`tensorboard.preview_frames`: how many render-vs-truth frames TensorBoard gets (>= 0)."""
    count = _section(cfg, "tensorboard").get("preview_frames")
    return require_int("preview_frames", count, minimum=0, prefix="tensorboard.")


def _hparams_choice(cfg: Mapping[str, Any]) -> str:
    """`tensorboard.hparams`: one of HPARAMS_CHOICES (default `swept`)."""
    choice = _section(cfg, "tensorboard").get("hparams", "swept")
    if choice not in HPARAMS_CHOICES:
        raise InputError(
            f"tensorboard.hparams must be one of {list(HPARAMS_CHOICES)}, got {choice!r}"
        )
    return choice


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
