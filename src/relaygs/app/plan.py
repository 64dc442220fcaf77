"""Validate a resolved run config and derive every node's stage config before any work starts.

A stage receives only `seed`, `train` and its own section (node `overrides` merged, step counts
scaled by the budget). The other sections are dataclasses Hydra checks on compose."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, fields
from enum import Enum
from pathlib import Path
from typing import Any, TypeVar

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from relaygs.app.scenes import SceneSpec, scene_spec
from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder
from relaygs.pipeline import Node, Pipeline, load_pipeline
from relaygs.pipeline.spec import names_a_file, parse_pipeline
from relaygs.pipeline.store import ON_CORRUPT_CHOICES
from relaygs.splat import BACKENDS

HParams = Enum("HParams", {"swept": "swept", "all": "all"})
"""`tensorboard.hparams`: log the swept settings, or the whole config too."""
OnCorrupt = Enum("OnCorrupt", {name: name for name in ON_CORRUPT_CHOICES})
Backend = Enum("Backend", {name: name for name in BACKENDS})
MAX_THREADS = 1024
"""Most torch CPU threads a job may ask for: more failed in the OpenMP runtime at job start."""

StageValidator = Callable[[str, Mapping[str, Any]], None]
"""Checks a stage type's config; raises a one-line InputError naming the bad key."""
T = TypeVar("T")


def _require(condition: bool, where: str, value: Any, expected: str) -> None:
    """Raise a one-line InputError `where: expected <expected>, got <value>` unless `condition`."""
    if not condition:
        raise InputError(f"{where}: expected {expected}, got {value!r}")


@dataclass
class RunSettings:
    """The top-level settings of a run besides its sections."""

    seed: int = 0
    variant: str = MISSING
    experiment_name: str | None = None
    threads: int | None = None

    def validate(self) -> None:
        """Ranges; a variant names a job's folder `<job>_<variant>`: no path separator."""
        _require(self.seed >= 0, "seed", self.seed, "an int >= 0")
        fits = self.threads is None or 1 <= self.threads <= MAX_THREADS
        _require(fits, "threads", self.threads, f"null or an int in [1, {MAX_THREADS}]")
        plain = not any(separator in self.variant for separator in "/\\")
        _require(plain, "variant", self.variant, "a plain name (no / or \\)")


@dataclass
class TensorBoardSettings:
    """`tensorboard`: what a job logs for TensorBoard; never enters a key."""

    preview_frames: int = 4
    hparams: HParams = HParams.swept

    def validate(self) -> None:
        """A frame count >= 0."""
        frames = self.preview_frames
        _require(frames >= 0, "tensorboard.preview_frames", frames, "an int >= 0")


@dataclass
class ReportSettings:
    """`report`: the variant the Δ column compares against (null: job 0's)."""

    reference: str | None = None


@dataclass
class PathSettings:
    """`paths`: where runs and the scene cache go."""

    outputs: str = MISSING
    scenes: str = MISSING


@dataclass
class ArtifactSettings:
    """`artifacts`: the store's folder and what a corrupt artifact does."""

    root: str = MISSING
    on_corrupt: OnCorrupt = OnCorrupt.rebuild


@dataclass
class SplatSettings:
    """`splat`: the splatting core's backend; never enters a key."""

    backend: Backend = Backend.auto


@dataclass
class BudgetSettings:
    """`budget`: a name, and the multiplier of the step counts its `scaled_keys` name."""

    name: str | None = None
    multiplier: float = 1.0
    scaled_keys: list[str] = field(default_factory=lambda: ["steps"])

    def validate(self) -> None:
        """The multiplier is a finite number > 0."""
        value = self.multiplier
        _require(0 < value < math.inf, "budget.multiplier", value, "a finite number > 0")


SECTIONS: dict[str, type] = {
    "tensorboard": TensorBoardSettings,
    "report": ReportSettings,
    "paths": PathSettings,
    "artifacts": ArtifactSettings,
    "splat": SplatSettings,
}
"""Sections Hydra checks through their schema (`<name>/schema`); `plan_run` checks `budget`."""
TOP_LEVEL_KEYS = frozenset(
    {"seed", "variant", "experiment_name", "threads", "train", "eval", "scene", "pipeline"}
    | {"budget", *SECTIONS}
)
"""Top-level keys of a run config besides one section per stage type."""
for _name, _schema in SECTIONS.items():
    ConfigStore.instance().store(group=_name, name="schema", node=_schema)


@dataclass(frozen=True)
class RunPlan:
    """Everything a run needs, validated: the pipeline, each node's stage config, the scene,
    the run's labels; `stage_types` are all implemented ones, run here or not."""

    pipeline: Pipeline
    stage_types: frozenset[str]
    node_configs: dict[str, dict[str, Any]]
    scene: SceneSpec
    run: RunSettings
    reference: str | None
    on_corrupt: str
    artifacts_root: Path
    scenes_dir: Path
    eval_config: dict[str, Any]
    preview_frames: int
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
    one-line InputErrors naming the field."""
    unknown = sorted(set(cfg) - TOP_LEVEL_KEYS - set(stage_types))
    if unknown:  # an experiment file without `# @package _global_` lands under `experiment`
        raise InputError(f"top level: unknown setting(s) {unknown}")
    pipeline = _pipeline(cfg, stage_types, accepted_upstream)
    run = _settings(RunSettings, cfg, "")
    paths = _settings(PathSettings, cfg, "paths")
    artifacts = _settings(ArtifactSettings, cfg, "artifacts")
    tensorboard = _settings(TensorBoardSettings, cfg, "tensorboard")
    splat = _settings(SplatSettings, cfg, "splat")
    report = _settings(ReportSettings, cfg, "report")
    budget = _settings(BudgetSettings, cfg, "budget")
    _require_stage_setting_names(cfg, stage_types, budget.scaled_keys)
    eval_config = {"seed": run.seed, "train": _section(cfg, "train"), "eval": _section(cfg, "eval")}
    for what, path in (
        ("paths.outputs", paths.outputs),
        ("paths.scenes", paths.scenes),
        ("artifacts.root", artifacts.root),
    ):
        require_creatable_folder(Path(path), what)
    node_configs = {}
    for node in pipeline.topological_order():
        section = _section(cfg, node.stage)
        where = f"{pipeline.path}: node {node.name!r} overrides"
        merged = merge_overrides(section, node.overrides, where)
        scaled = scale_steps(merged, budget.multiplier, budget.scaled_keys)
        node_configs[node.name] = {
            "seed": run.seed,
            "train": copy.deepcopy(eval_config["train"]),
            node.stage: scaled,
        }
        evaluated = node is pipeline.output_node
        validate(node.stage, {**node_configs[node.name], **(eval_config if evaluated else {})})
    return RunPlan(
        pipeline=pipeline,
        stage_types=frozenset(stage_types),
        node_configs=node_configs,
        scene=scene_spec(_section(cfg, "scene")),
        run=run,
        reference=report.reference,
        on_corrupt=artifacts.on_corrupt.name,
        artifacts_root=Path(artifacts.root),
        scenes_dir=Path(paths.scenes),
        eval_config=eval_config,
        preview_frames=tensorboard.preview_frames,
        splat_backend=splat.backend.name,
        hparams=tensorboard.hparams.name,
    )


def _settings(cls: type[T], cfg: Mapping[str, Any], name: str) -> T:
    """Section `name` of `cfg` (top-level fields for "") parsed as `cls`, ranges validated."""
    from relaygs.stages.config import parse_section  # loaded with the stages a run plans for

    names = {each.name for each in fields(cls)}
    data = _section(cfg, name) if name else {k: v for k, v in cfg.items() if k in names}
    settings = parse_section(cls, data, name)
    if hasattr(settings, "validate"):
        settings.validate()
    return settings


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
    """`section` with each positive int named in `keys` (at any depth) times `multiplier`,
    rounded and kept >= 1; zeros ("off") and negatives (left for validation) are unchanged."""
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
    """A copy of the config section `name`, which must be a mapping (an experiment file's
    `pipeline: 4dgs` would set the group's section to a value instead of choosing its file)."""
    section = cfg.get(name)
    _require(isinstance(section, Mapping), name, section, "a config section (a mapping)")
    return copy.deepcopy(dict(section))


def _pipeline(
    cfg: Mapping[str, Any],
    stage_types: Collection[str],
    accepted_upstream: Mapping[str, Collection[str]] | None,
) -> Pipeline:
    """The pipeline `pipeline.name` names; a composed section whose nodes differ from its file
    (`pipeline.name` changed alone, a node set on the command line) is refused."""
    section = _section(cfg, "pipeline")
    name = section.get("name")
    named = not isinstance(name, bool) and isinstance(name, str | int) and name != ""
    _require(named, "pipeline.name", name, "a conf/pipeline/<name>.yaml's name or a file's path")
    declared = load_pipeline(str(name), stage_types, accepted_upstream)
    if names_a_file(str(name)) or parse_pipeline(section, declared.path) == declared:
        return declared
    raise InputError(
        f"pipeline: the config's nodes differ from those of {declared.path}: choose a "
        f"pipeline with pipeline=<name>, and change its nodes in its file"
    )


def _require_stage_setting_names(
    cfg: Mapping[str, Any], stage_types: Collection[str], scaled_keys: Collection[str]
) -> None:
    """Each of `budget.scaled_keys` names some stage setting: a typo would scale nothing."""
    sections = [cfg[stage] for stage in stage_types if isinstance(cfg.get(stage), Mapping)]
    unknown = sorted(set(scaled_keys) - set().union(*map(_setting_names, sections)))
    _require(not unknown, "budget.scaled_keys", unknown, "names of stage settings ('steps')")


def _setting_names(section: Mapping[str, Any]) -> set[str]:
    """Every key of `section` and of the mappings nested in it."""
    nested = (_setting_names(value) for value in section.values() if isinstance(value, Mapping))
    return set(section).union(*nested)
