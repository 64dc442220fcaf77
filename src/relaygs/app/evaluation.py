"""Evaluation through the artifact store: an `eval` entry keyed by the model, the `eval`
settings, the device (render FPS) and the scene, so a job whose model was already evaluated the
same way reads the metrics back. Its tensors hold the per-view records (kept out of the
manifest, which `artifacts ls` prints). Bump EVAL_SCHEMA_VERSION when what it reports changes."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import torch

from relaygs.data.fingerprint import digest
from relaygs.per_view import PER_VIEW, from_tensors, to_tensors
from relaygs.pipeline import Artifact, ArtifactStore, LineageEntry, PipelineRun
from relaygs.pipeline.keys import artifact_key, key_config
from relaygs.pipeline.manifest import built_by
from relaygs.pipeline.store import OnCorrupt

EVAL_STAGE = "eval"
EVAL_SCHEMA_VERSION = 3

EvaluateFn = Callable[[Any, Artifact, dict[str, Any]], Mapping[str, Any]]


@dataclass(frozen=True)
class Evaluation:
    """Test metrics of a run's output, whether they were read back, and the seconds it took."""

    metrics: dict[str, Any]
    key: str
    cache_hit: bool
    wall_seconds: float
    replaced_corrupt: str | None = None  # what was wrong with a stored evaluation it redid
    built_by: str | None = None  # the job that evaluated (manifest provenance `BUILT_BY`)

    @property
    def seconds_computed(self) -> float:
        """Seconds this job spent evaluating (0 when the metrics were read back)."""
        return 0.0 if self.cache_hit else self.wall_seconds

    def seconds_built_by(self, builder: str) -> float:
        """The evaluation's seconds when job `builder` made it, now or before an interruption."""
        return self.wall_seconds if self.built_by == builder else 0.0


def evaluate_through_store(
    store: ArtifactStore,
    scene: Any,
    run: PipelineRun,
    eval_config: dict[str, Any],
    evaluate: EvaluateFn,
    on_corrupt: OnCorrupt = "rebuild",
    provenance: Mapping[str, Any] | None = None,
) -> Evaluation:
    """The metrics of `run.output` on `scene`: read from the store, or computed by `evaluate`
    and stored once (with `provenance` in its manifest), even when parallel jobs ask."""
    output = run.reports[-1]
    keyed = evaluation_config(eval_config)
    fingerprint = str(scene.fingerprint)
    key = artifact_key(EVAL_STAGE, EVAL_SCHEMA_VERSION, keyed, fingerprint, [output.key])

    def build() -> Artifact:
        metrics = dict(evaluate(scene, run.output, eval_config))
        records = metrics.pop(PER_VIEW, None)
        tensors = to_tensors(records) if records is not None else {}
        return Artifact(EVAL_STAGE, tensors=tensors, meta={"metrics": metrics})

    artifact, info = store.get_or_build(
        EVAL_STAGE,
        key,
        build,
        config=keyed,
        lineage=[LineageEntry(output.node, output.stage, output.key)],
        provenance={
            **(provenance or {}),
            "schema_version": EVAL_SCHEMA_VERSION,
            "scene": fingerprint,
        },
        on_corrupt=on_corrupt,
    )
    metrics = dict(artifact.meta["metrics"])
    records = from_tensors(artifact.tensors)
    if records is not None:
        metrics[PER_VIEW] = records
    builder = built_by(info.provenance)
    return Evaluation(
        metrics, key, info.cache_hit, info.wall_seconds, info.replaced_corrupt, builder
    )


def evaluation_config(eval_config: Mapping[str, Any]) -> dict[str, Any]:
    """What shapes an evaluation's result: `eval`, the device and on the CPU torch's threads."""
    device = str(eval_config["train"]["device"])
    keyed: dict[str, Any] = {"eval": dict(eval_config["eval"]), "device": device}
    if torch.device(device).type == "cpu":
        keyed["cpu_threads"] = torch.get_num_threads()
    return key_config(keyed)


def test_set_id(scene: Any, metrics: Mapping[str, Any]) -> str:
    """12 hex digits naming the images a run was scored on (scene folder, downscale, test
    cameras, evaluated views): the sweep report compares PSNR only within one id."""
    records = metrics.get(PER_VIEW)
    views = None if records is None else sorted([r["frame"], r["camera"]] for r in records)
    payload = {
        "scene": str(scene.root),
        "downscale": scene.downscale,
        "test_cameras": [camera.camera_id for camera in scene.test_cameras],
        "views": views,
    }
    return digest(payload)[:12]
