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
        "decouple": "10647e19df924c3b",
        "relay": "ebd49aacb483e62a",
        "deform": "7a82dd54034fda46",
    },
    "pipeline=4dgs": {"warmup": "75a65f60ac205411", "deform": "f762d9028c22c2c8"},
    "pipeline=no_stage2": {
        "decouple": "10647e19df924c3b",
        "replicate": "c4baf092cf838273",
        "deform": "8f95ba72dd1a6aed",
    },
    "pipeline=no_copies": {"decouple": "10647e19df924c3b", "deform": "804d5ae7901675e8"},
    "+component=no_gamma": {
        "decouple": "10647e19df924c3b",
        "relay": "ebd49aacb483e62a",
        "deform": "9ecf91f80c8c9e6f",
    },
    "+component=no_isolation": {
        "decouple": "10647e19df924c3b",
        "relay": "ebd49aacb483e62a",
        "deform": "bbfbaf8d2628bde5",
    },
    "+component=no_pseudo_views": {
        "decouple": "10647e19df924c3b",
        "relay": "8798f0f6fab7ff38",
        "deform": "c88aba98f4c070f2",
    },
    "relay.k=128": {
        "decouple": "10647e19df924c3b",
        "relay": "01fda0ecd7d0ceba",
        "deform": "dfb8744d1b9ec574",
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
