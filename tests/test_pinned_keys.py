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
        "relay": "595965c28687dacc",
        "deform": "03264a52167d4cde",
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
        "relay": "595965c28687dacc",
        "deform": "a74c7bcc88fbefb3",
    },
    "+component=no_isolation": {
        "decouple": "051ff8a87afd150e",
        "relay": "595965c28687dacc",
        "deform": "40783b2e75364e40",
    },
    "+component=no_pseudo_views": {
        "decouple": "051ff8a87afd150e",
        "relay": "febf4755cc0afa38",
        "deform": "0c927e87ff6b8e6f",
    },
    "relay.k=128": {
        "decouple": "051ff8a87afd150e",
        "relay": "0c60db36bd00d99c",
        "deform": "fcf489ea935d176a",
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
