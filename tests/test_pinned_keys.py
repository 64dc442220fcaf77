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
        "decouple": "88c965ef8b3f3aec",
        "relay": "eb1c616583571324",
        "deform": "0c775e5b500126c6",
    },
    "pipeline=4dgs": {"warmup": "e10663705da9d570", "deform": "2cf50733c0f87eb8"},
    "pipeline=no_stage2": {
        "decouple": "88c965ef8b3f3aec",
        "replicate": "4b61fe55302490bb",
        "deform": "b4e638164531c860",
    },
    "pipeline=no_copies": {"decouple": "88c965ef8b3f3aec", "deform": "1bfe04e101d6312a"},
    "+component=no_gamma": {
        "decouple": "88c965ef8b3f3aec",
        "relay": "eb1c616583571324",
        "deform": "97b84d9cc4da56ae",
    },
    "+component=no_isolation": {
        "decouple": "88c965ef8b3f3aec",
        "relay": "eb1c616583571324",
        "deform": "a16279e09f0f6246",
    },
    "+component=no_pseudo_views": {
        "decouple": "88c965ef8b3f3aec",
        "relay": "1498eb78abcb4d09",
        "deform": "c335c766f8575473",
    },
    "relay.k=128": {
        "decouple": "88c965ef8b3f3aec",
        "relay": "46af6ee14ffb28da",
        "deform": "258c74ccb0c809fd",
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
