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
        "relay": "6e71326cb478a082",
        "deform": "7094fd83ea820932",
    },
    "pipeline=4dgs": {"warmup": "950e91bf2d07be4a", "deform": "fa9f4efe3753970d"},
    "pipeline=no_stage2": {
        "decouple": "051ff8a87afd150e",
        "replicate": "aaae1cf4be8b3f0f",
        "deform": "52de62357eee271e",
    },
    "pipeline=no_copies": {"decouple": "051ff8a87afd150e", "deform": "b18eaeea932cf6f3"},
    "+component=no_gamma": {
        "decouple": "051ff8a87afd150e",
        "relay": "6e71326cb478a082",
        "deform": "43981c9c90b20030",
    },
    "+component=no_isolation": {
        "decouple": "051ff8a87afd150e",
        "relay": "6e71326cb478a082",
        "deform": "6cddd7dd0431b4ff",
    },
    "+component=no_pseudo_views": {
        "decouple": "051ff8a87afd150e",
        "relay": "466a7ee2687dcc8c",
        "deform": "f85b78f8859ccbba",
    },
    "relay.k=128": {
        "decouple": "051ff8a87afd150e",
        "relay": "a9f2ce76eea176f2",
        "deform": "4c462740689eae9c",
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
