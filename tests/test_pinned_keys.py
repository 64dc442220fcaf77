"""The artifact keys of the shipped pipelines and ablations, pinned: a refactor of the stage
registry or of config handling that changed one would orphan every stored artifact."""

from types import SimpleNamespace

import pytest
import torch
from omegaconf import OmegaConf

from fake_stages import compose_config
from relaygs.app.plan import plan_run
from relaygs.app.suite import load_stage_suite
from relaygs.pipeline import Artifact, run_pipeline
from relaygs.pipeline.store import ArtifactStore

SCENE = SimpleNamespace(fingerprint="pinned-scene", num_frames=64)
"""A stand-in scene: keys read only its fingerprint, canonical forms its frame count."""

PINNED = {
    "pipeline=relaygs": {
        "decouple": "051ff8a87afd150e",
        "relay": "4badfcb3b40b5b35",
        "deform": "09cc891dd57f8e1a",
    },
    "pipeline=4dgs": {"warmup": "950e91bf2d07be4a", "deform": "3c12c832529165b5"},
    "pipeline=no_stage2": {
        "decouple": "051ff8a87afd150e",
        "replicate": "aaae1cf4be8b3f0f",
        "deform": "14795ab5fa6d8ed8",
    },
    "pipeline=no_copies": {"decouple": "051ff8a87afd150e", "deform": "f2f8a819abd75b65"},
    "+component=no_gamma": {
        "decouple": "051ff8a87afd150e",
        "relay": "4badfcb3b40b5b35",
        "deform": "85b7aef0c0821921",
    },
    "+component=no_isolation": {
        "decouple": "051ff8a87afd150e",
        "relay": "4badfcb3b40b5b35",
        "deform": "2659c51d4cc8e061",
    },
    "+component=no_pseudo_views": {
        "decouple": "051ff8a87afd150e",
        "relay": "c25bfaf9660a0e6f",
        "deform": "301f5f628d1313bf",
    },
    "relay.k=128": {
        "decouple": "051ff8a87afd150e",
        "relay": "05ee3e94ebe8c740",
        "deform": "663de394bd1550d0",
    },
}
"""Each node's key (its first 16 hex digits) at the default scene settings and `small` budget;
`relay.k=128` is capped at the 64 frames by relay's canonical form."""


def _node_keys(override: str, tmp_path) -> dict[str, str]:
    """Each node's key as the runner computes it, on stage functions that build nothing."""
    suite = load_stage_suite()
    config = compose_config([override], tmp_path)
    plan = plan_run(
        OmegaConf.to_container(config, resolve=True),
        suite.stages,
        suite.validate,
        suite.accepted_upstream,
    )
    stub = {stage: _stub(stage) for stage in suite.stages}
    run = run_pipeline(
        plan.pipeline,
        stub,
        SCENE,
        plan.config_for,
        ArtifactStore(tmp_path / "store"),
        schema_versions=suite.schema_versions,
        canonical=suite.canonical,
    )
    return {report.node: report.key[:16] for report in run.reports}


def _stub(stage: str):
    """A stage function that returns an empty artifact of type `stage`."""
    return lambda scene, upstream, cfg: Artifact(stage, {"x": torch.zeros(1)}, {})


@pytest.mark.parametrize("override", sorted(PINNED))
def test_shipped_pipelines_keep_their_artifact_keys(override, tmp_path):
    assert _node_keys(override, tmp_path) == PINNED[override]
