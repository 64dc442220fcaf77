"""Settings that mean the same run (relay k >= T frames) share one artifact key and run in
their canonical form; results keep the value the user set."""

import copy
import functools
import json
from types import SimpleNamespace

import pandas as pd
import pytest
from omegaconf import OmegaConf

from fake_stages import FakeStages, compose_config
from relaygs.app.task import run_task
from relaygs.commands import run as run_module
from relaygs.pipeline import ArtifactStore
from relaygs.stages import canonical_config

FRAMES = 64
SCENE_64 = [f"scene.frames={FRAMES}", "scene.width=16", "scene.height=9"]


def test_relay_and_replicate_k_at_or_above_the_frame_count_is_one_segment_of_t():
    scene = SimpleNamespace(num_frames=FRAMES)
    cfg = {"seed": 0, "train": {"steps": 5}, "relay": {"k": 128, "p": 3}}
    canonical = canonical_config("relay", cfg, scene)
    assert canonical == {"seed": 0, "train": {"steps": 5}, "relay": {"k": FRAMES, "p": 3}}
    assert cfg["relay"]["k"] == 128  # the input is not changed
    for k in (1, 32, FRAMES):
        assert canonical_config("relay", {"relay": {"k": k}}, scene)["relay"]["k"] == k
    assert canonical_config("relay", {"relay": {"k": FRAMES + 1}}, scene)["relay"]["k"] == FRAMES
    assert canonical_config("replicate", {"replicate": {"k": 100}}, scene)["replicate"]["k"] == 64
    still = {"seed": 0, "deform": {"isolate_fg_bg": True, "background_motion": False}}
    assert canonical_config("deform", still, scene) == still
    for same in ({"background_motion": True}, {"isolate_fg_bg": False, "background_motion": False}):
        canonical = canonical_config("deform", {"deform": same}, scene)["deform"]
        assert "background_motion" not in canonical  # a moving background keeps its old key
    float32 = canonical_config("deform", {"deform": {"matmul_dtype": "float32"}}, scene)
    assert float32["deform"] == {}  # float32 products keep the keys from before the setting
    reduced = {"deform": {"matmul_dtype": "bfloat16"}}
    assert canonical_config("deform", reduced, scene) == reduced
    unpatched = {"deform": {"frame_patches": 0, "patch_opacity": 0.3}}
    assert canonical_config("deform", unpatched, scene)["deform"] == {}  # no patch, no opacity
    patched = {"deform": {"frame_patches": 200, "patch_opacity": 0.3}}
    assert canonical_config("deform", patched, scene) == patched
    one_at_a_time = canonical_config("relay", {"relay": {"k": 1, "segments_per_step": 1}}, scene)
    assert one_at_a_time["relay"] == {"k": 1}  # relays keep the keys they had before the setting
    several = canonical_config("relay", {"relay": {"k": 1, "segments_per_step": 4}}, scene)
    assert several["relay"] == {"k": 1, "segments_per_step": 4}


@pytest.fixture(scope="module")
def base_config(tmp_path_factory):
    """The default config on a tiny 64-frame scene, every output under one temp folder."""
    outputs = tmp_path_factory.mktemp("outputs")
    cfg = compose_config([*SCENE_64, "budget=smoke"], outputs)
    return OmegaConf.to_container(cfg, resolve=True)


def _run_k(config, k, run_dir, fakes):
    config = copy.deepcopy(config)
    config["relay"]["k"] = k
    config["artifacts"]["root"] = str(run_dir.parent / "artifacts")
    return run_task(
        config,
        run_dir=run_dir,
        original_cwd=run_dir,
        overrides=[f"relay.k={k}"],
        suite=fakes.suite(),
    )


def test_k64_and_k128_on_64_frames_share_one_artifact_and_keep_the_swept_value(
    base_config, tmp_path
):
    fakes = FakeStages(canonical=canonical_config)
    at_t = _run_k(base_config, 64, tmp_path / "k64", fakes)
    above_t = _run_k(base_config, 128, tmp_path / "k128", fakes)
    assert above_t["output_key"] == at_t["output_key"]
    assert (above_t["cache_hits"], above_t["train_s_computed"]) == (3, 0)
    assert fakes.ran("relay") == 1 and fakes.ran("deform") == 1
    assert [cfg["relay"]["k"] for stage, cfg in fakes.calls if stage == "relay"] == [64]
    (key,) = [path.name for path in (tmp_path / "artifacts" / "relay").iterdir()]
    assert ArtifactStore(tmp_path / "artifacts").manifest("relay", key).config["relay"]["k"] == 64
    assert (at_t["relay.k"], above_t["relay.k"]) == (64, 128)
    written = json.loads((tmp_path / "k128" / "result.json").read_text())
    assert written["relay.k"] == 128


def test_a_k_sweep_builds_one_relay_per_distinct_segmentation(monkeypatch, tmp_path):
    fakes = FakeStages(canonical=canonical_config)
    monkeypatch.setattr(run_module, "load_stage_suite", fakes.suite)
    monkeypatch.setattr(run_module, "run_task", functools.partial(run_task, suite=fakes.suite()))
    monkeypatch.chdir(tmp_path)
    args = ["-m", "relay.k=32,64,128", "variant=k${relay.k}", "budget=smoke", *SCENE_64]
    assert run_module.main(args) == 0
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    table = pd.read_csv(sweep / "summary.csv")
    assert list(table["relay.k"]) == [32, 64, 128]
    assert list(table.cache_hits) == [0, 1, 3]
    assert table.output_key[1] == table.output_key[2] != table.output_key[0]
    assert (fakes.ran("decouple"), fakes.ran("relay"), fakes.ran("deform")) == (1, 2, 2)
