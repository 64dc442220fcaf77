"""Pipeline topologies (`conf/pipeline/<name>.yaml`, format in docs/artifacts.md): nodes, their
stage types, upstreams and `overrides`; evaluation reads the one output node."""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from relaygs.errors import InputError
from relaygs.paths import config_dir

NODE_FIELDS = frozenset({"stage", "upstream", "overrides"})
PIPELINE_FIELDS = frozenset({"name", "description", "nodes"})
_NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


@dataclass(frozen=True)
class Node:
    """One step of a pipeline: a name, the stage type it runs, the nodes it reads, and the
    settings it pins over its stage's config section (`overrides`, nested; treat as read-only)."""

    name: str
    stage: str
    upstream: tuple[str, ...]
    overrides: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Pipeline:
    """A validated stage DAG loaded from one YAML file."""

    name: str
    path: Path
    description: str
    nodes: dict[str, Node]

    def topological_order(self) -> list[Node]:
        """Nodes, upstreams first, ties in file order (Kahn); a cycle is an InputError naming it."""
        remaining = dict(self.nodes)
        done: set[str] = set()
        order: list[Node] = []
        while remaining:
            ready = [node for node in remaining.values() if set(node.upstream) <= done]
            if not ready:
                raise InputError(f"{self.path}: cycle {_find_cycle(remaining)}")
            for node in ready:
                order.append(node)
                done.add(node.name)
                del remaining[node.name]
        return order

    @property
    def output_node(self) -> Node:
        """The single node no other node depends on (what evaluation reads)."""
        consumed = {name for node in self.nodes.values() for name in node.upstream}
        return next(node for node in self.nodes.values() if node.name not in consumed)

    @property
    def stage_types(self) -> set[str]:
        """Every stage type the pipeline runs."""
        return {node.stage for node in self.nodes.values()}


def pipeline_path(name: str) -> Path:
    """Where pipeline `name` is declared: `conf/pipeline/<name>.yaml`, a config group file."""
    return config_dir() / "pipeline" / f"{name}.yaml"


def available_pipelines() -> list[str]:
    """Names of the pipelines shipped in `conf/pipeline/`."""
    return sorted(path.stem for path in (config_dir() / "pipeline").glob("*.yaml"))


def names_a_file(name_or_path: str | Path) -> bool:
    """Whether `pipeline.name` is a path to a pipeline file rather than a shipped name."""
    text = str(name_or_path)
    return "/" in text or text.endswith((".yaml", ".yml"))


def load_pipeline(
    name_or_path: str | Path,
    known_stages: Collection[str] | None = None,
    accepted_upstream: Mapping[str, Collection[str]] | None = None,
) -> Pipeline:
    """Load and check a pipeline by name or file path: unknown stage types and, with
    `accepted_upstream` (type → upstream types it reads), misfit upstreams are InputErrors."""
    path = _resolve(name_or_path)
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise InputError(f"{path}: cannot read pipeline ({_read_error(error)})") from error
    return parse_pipeline(raw, path, known_stages, accepted_upstream)


def parse_pipeline(
    raw: Any,
    path: Path,
    known_stages: Collection[str] | None = None,
    accepted_upstream: Mapping[str, Collection[str]] | None = None,
) -> Pipeline:
    """Build and check a pipeline from its mapping (a file's content, or the composed config's
    `pipeline` section) as `load_pipeline` does; errors name `path`, where it is declared."""
    pipeline = _parse(path, raw)
    _check_graph(pipeline, known_stages, accepted_upstream or {})
    return pipeline


def _read_error(error: Exception) -> str:
    """Why a pipeline file could not be read: a YAML problem with its line, else the first line."""
    mark = getattr(error, "problem_mark", None)
    if isinstance(error, yaml.MarkedYAMLError) and error.problem and mark is not None:
        return f"{error.problem} at line {mark.line + 1}, column {mark.column + 1}"
    return str(error).splitlines()[0] if str(error) else type(error).__name__


def _resolve(name_or_path: str | Path) -> Path:
    """A path is used as given; a bare name must be one of the shipped pipelines."""
    text = str(name_or_path)
    if names_a_file(text):
        path = Path(text).expanduser().resolve()
        if not path.is_file():
            raise InputError(f"pipeline file {path} does not exist")
        return path
    path = pipeline_path(text)
    if not path.is_file():
        available = ", ".join(available_pipelines())
        raise InputError(f"unknown pipeline {text!r}: no {path} (available: {available})")
    return path


def _parse(path: Path, raw: Any) -> Pipeline:
    """Check the file's shape and build the Pipeline (graph checks come after)."""
    if not isinstance(raw, dict):
        raise InputError(f"{path}: expected a mapping with 'nodes', got {type(raw).__name__}")
    unknown = sorted(set(raw) - PIPELINE_FIELDS)
    if unknown:
        raise InputError(f"{path}: unknown field(s) {unknown}; expected {sorted(PIPELINE_FIELDS)}")
    nodes_raw = raw.get("nodes")
    if not isinstance(nodes_raw, dict) or not nodes_raw:
        raise InputError(f"{path}: 'nodes' must be a non-empty mapping of node name to node")
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise InputError(f"{path}: 'description' must be a string")
    nodes = {str(name): _parse_node(path, name, spec) for name, spec in nodes_raw.items()}
    return Pipeline(name=path.stem, path=path, description=description, nodes=nodes)


def _parse_node(path: Path, name: Any, spec: Any) -> Node:
    """One node entry: `{stage: TYPE, upstream: [NODE, ...], overrides: {KEY: VALUE, ...}}`."""
    where = f"{path}: node {name!r}"
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise InputError(f"{where}: node names must match {_NAME_RE.pattern}")
    if not isinstance(spec, dict):
        raise InputError(f"{where}: expected a mapping with 'stage' and 'upstream'")
    unknown = sorted(set(spec) - NODE_FIELDS)
    if unknown:
        raise InputError(f"{where}: unknown field(s) {unknown}; expected {sorted(NODE_FIELDS)}")
    stage = spec.get("stage")
    if not isinstance(stage, str) or not _NAME_RE.fullmatch(stage):
        raise InputError(f"{where}: 'stage' must be a stage type name, got {stage!r}")
    upstream = spec.get("upstream", [])
    if not isinstance(upstream, list) or not all(isinstance(item, str) for item in upstream):
        raise InputError(f"{where}: 'upstream' must be a list of node names, got {upstream!r}")
    if len(set(upstream)) != len(upstream):
        raise InputError(f"{where}: 'upstream' lists a node twice: {upstream}")
    overrides = spec.get("overrides", {})
    if not isinstance(overrides, dict) or not all(isinstance(key, str) for key in overrides):
        raise InputError(
            f"{where}: 'overrides' must be a mapping of setting names, got {overrides!r}"
        )
    return Node(name=name, stage=stage, upstream=tuple(upstream), overrides=overrides)


def _check_graph(
    pipeline: Pipeline,
    known_stages: Collection[str] | None,
    accepted_upstream: Mapping[str, Collection[str]],
) -> None:
    """Unknown upstreams or stage types, upstreams a type does not read, cycles, two outputs."""
    for node in pipeline.nodes.values():
        for parent in node.upstream:
            if parent not in pipeline.nodes:
                raise InputError(
                    f"{pipeline.path}: node {node.name!r} has unknown upstream {parent!r} "
                    f"(nodes: {', '.join(pipeline.nodes)})"
                )
        if known_stages is not None and node.stage not in known_stages:
            raise InputError(
                f"{pipeline.path}: node {node.name!r} has unknown stage type {node.stage!r} "
                f"(known: {', '.join(sorted(known_stages))})"
            )
        if node.stage in accepted_upstream:
            _check_upstream_types(pipeline, node, accepted_upstream[node.stage])
    pipeline.topological_order()  # refuses a cycle
    consumed = {name for node in pipeline.nodes.values() for name in node.upstream}
    outputs = [name for name in pipeline.nodes if name not in consumed]
    if len(outputs) != 1:
        raise InputError(
            f"{pipeline.path}: a pipeline must end in exactly one output node, found {outputs}"
        )


def _check_upstream_types(pipeline: Pipeline, node: Node, accepted: Collection[str]) -> None:
    """`node` reads no upstream when its stage type takes none, else exactly one node of an
    accepted stage type (the stage would refuse it only once its upstreams have trained)."""
    found = [f"node {name!r} of type {pipeline.nodes[name].stage!r}" for name in node.upstream]
    if not accepted and found:
        expected = "no upstream node"
    elif accepted and (len(found) != 1 or pipeline.nodes[node.upstream[0]].stage not in accepted):
        expected = f"one upstream node of stage type {' or '.join(sorted(accepted))}"
    else:
        return
    raise InputError(
        f"{pipeline.path}: node {node.name!r} (stage {node.stage!r}) reads {expected} "
        f"(its StageSpec's upstream), got {', '.join(found) or 'none'}"
    )


def _find_cycle(nodes: dict[str, Node]) -> str:
    """'a -> b -> a' for one cycle among nodes that all wait on each other."""
    path = [next(iter(nodes))]
    while True:
        parent = next(name for name in nodes[path[-1]].upstream if name in nodes)
        if parent in path:
            cycle = [*path[path.index(parent) :], parent]
            return " -> ".join(reversed(cycle))
        path.append(parent)
