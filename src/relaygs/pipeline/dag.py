"""Run a pipeline's stages in order through the artifact store, reusing what is stored;
independent of Hydra and of the real stages (a scene needs only a `fingerprint`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Protocol

from relaygs.errors import InputError, resource_error
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.keys import artifact_key, key_config
from relaygs.pipeline.manifest import LineageEntry, built_by
from relaygs.pipeline.spec import Node, Pipeline
from relaygs.pipeline.store import ArtifactStore, OnCorrupt

DEFAULT_SCHEMA_VERSION = 1


class Scene(Protocol):
    """What the runner needs of a scene: a stable content fingerprint."""

    fingerprint: str


StageFn = Callable[[Any, dict[str, Artifact], dict[str, Any]], Artifact]
"""A stage: `(scene, upstream artifacts by node name, stage config) -> Artifact`."""

CanonicalFn = Callable[[str, Mapping[str, Any], Any], Mapping[str, Any]]
"""`(stage type, stage config, scene) -> canonical stage config`: the one form, keyed and run,
of configs that mean the same computation (so they share one artifact)."""


@dataclass(frozen=True)
class NodeReport:
    """One node's key, whether the store had it, its own build time (the manifest's on a hit),
    that plus every ancestor's (`lineage_seconds`) and its size from its manifest."""

    node: str
    stage: str
    key: str
    cache_hit: bool
    wall_seconds: float
    lineage_seconds: float
    path: Path
    size_mb: float
    replaced_corrupt: str | None = None  # what was wrong with the stored artifact it rebuilt
    notes: tuple[str, ...] = ()  # what the artifact says a user should know (`Artifact.notes`)
    built_by: str | None = None  # the job that built it (manifest provenance `BUILT_BY`)


@dataclass(frozen=True)
class PipelineRun:
    """The artifacts and per-node reports of one pipeline run, in topological order."""

    pipeline: Pipeline
    artifacts: dict[str, Artifact]
    reports: list[NodeReport]

    @property
    def output(self) -> Artifact:
        """The output node's artifact (what evaluation reads)."""
        return self.artifacts[self.pipeline.output_node.name]

    @property
    def train_seconds_total(self) -> float:
        """Build seconds of every node, cached ones included (the lineage's full cost)."""
        return sum(report.wall_seconds for report in self.reports)

    @property
    def train_seconds_computed(self) -> float:
        """Build seconds of the nodes this run actually computed."""
        return sum(report.wall_seconds for report in self.reports if not report.cache_hit)

    def train_seconds_built_by(self, builder: str) -> float:
        """Build seconds of the nodes that job `builder` (a `BUILT_BY` value) built, in this run
        or in an earlier, interrupted run of it (a sweep resumed in place)."""
        return sum(report.wall_seconds for report in self.reports if report.built_by == builder)


def run_pipeline(
    pipeline: Pipeline,
    stage_fns: Mapping[str, StageFn],
    scene: Scene,
    cfg_for: Callable[[Node], Mapping[str, Any]],
    store: ArtifactStore,
    *,
    schema_versions: Mapping[str, int] | None = None,
    on_corrupt: OnCorrupt = "rebuild",
    on_node_done: Callable[[NodeReport], None] | None = None,
    canonical: CanonicalFn | None = None,
    provenance: Mapping[str, Any] | None = None,
) -> PipelineRun:
    """Load or build each node's artifact in topological order, keyed by stage type, schema
    version, (`canonical`) config, scene fingerprint and upstream keys (docs/artifacts.md)."""
    missing = sorted(pipeline.stage_types - set(stage_fns))
    if missing:
        raise InputError(f"pipeline {pipeline.name!r}: no stage function for type(s) {missing}")
    versions = dict(schema_versions or {})
    fingerprint = str(scene.fingerprint)
    artifacts: dict[str, Artifact] = {}
    reports: dict[str, NodeReport] = {}
    ancestors: dict[str, set[str]] = {}
    for node in pipeline.topological_order():
        cfg = dict(cfg_for(node))
        if canonical is not None:
            cfg = dict(canonical(node.stage, cfg, scene))
        keyed_cfg = key_config(cfg)
        version = versions.get(node.stage, DEFAULT_SCHEMA_VERSION)
        upstream_keys = [reports[name].key for name in node.upstream]
        key = artifact_key(node.stage, version, keyed_cfg, fingerprint, upstream_keys)
        upstream = {name: artifacts[name] for name in node.upstream}
        lineage = [LineageEntry(n, reports[n].stage, reports[n].key) for n in node.upstream]
        try:
            artifact, info = store.get_or_build(
                node.stage,
                key,
                partial(stage_fns[node.stage], scene, upstream, cfg),
                config=keyed_cfg,
                lineage=lineage,
                provenance={
                    **(provenance or {}),
                    "node": node.name,
                    "schema_version": version,
                    "scene": fingerprint,
                },
                on_corrupt=on_corrupt,
            )
        except (OSError, MemoryError, RuntimeError) as error:
            # out of disk or memory: one line naming the node; anything else is a bug
            failure = resource_error(error, f"stage {node.name}")
            if failure is None:
                raise
            raise failure from error
        ancestors[node.name] = set(node.upstream).union(*(ancestors[n] for n in node.upstream))
        upstream_seconds = sum(reports[name].wall_seconds for name in ancestors[node.name])
        report = NodeReport(
            node=node.name,
            stage=node.stage,
            key=key,
            cache_hit=info.cache_hit,
            wall_seconds=info.wall_seconds,
            lineage_seconds=info.wall_seconds + upstream_seconds,
            path=info.path,
            size_mb=info.size_mb,
            replaced_corrupt=info.replaced_corrupt,
            notes=artifact.notes,
            built_by=built_by(info.provenance),
        )
        artifacts[node.name] = artifact
        reports[node.name] = report
        if on_node_done is not None:
            on_node_done(report)
    return PipelineRun(pipeline=pipeline, artifacts=artifacts, reports=list(reports.values()))
