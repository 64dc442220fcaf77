"""Artifact keys change with everything that shapes a result and with nothing else."""

import pytest

from refusals import refused
from relaygs.errors import InputError
from relaygs.pipeline.keys import artifact_key, canonical_json, is_non_key_name, key_config

BASE_CFG = {"steps": 100, "lr": {"xyz": 1.6e-4, "mlp": 1.6e-4}, "k": 16, "pseudo_views": True}
UP = ["a" * 64]


def _key(cfg=BASE_CFG, stage="relay", version=1, scene="scene-fp", upstream=UP):
    return artifact_key(stage, version, cfg, scene, upstream)


def test_key_is_a_sha256_hex_and_stable_under_reordering_and_tuples():
    key = _key()
    assert len(key) == 64 and int(key, 16) >= 0
    reordered = {"pseudo_views": True, "k": 16, "lr": {"mlp": 1.6e-4, "xyz": 1.6e-4}, "steps": 100}
    assert _key(cfg=reordered) == key
    assert _key(cfg={**BASE_CFG, "res": (64, 64)}) == _key(cfg={**BASE_CFG, "res": [64, 64]})
    assert _key(cfg={**BASE_CFG, "zero": -0.0}) == _key(cfg={**BASE_CFG, "zero": 0.0})
    assert _key(upstream=["a" * 64, "b" * 64]) != _key(upstream=["b" * 64, "a" * 64])


@pytest.mark.parametrize(
    "changed",
    [
        {"cfg": {**BASE_CFG, "k": 32}},
        {"cfg": {**BASE_CFG, "lr": {"xyz": 1.6e-4, "mlp": 1.7e-4}}},
        {"cfg": {**BASE_CFG, "steps": 100.0}},
        {"cfg": {**BASE_CFG, "pseudo_views": False}},
        {"cfg": {**BASE_CFG, "extra": None}},
        {"stage": "deform"},
        {"version": 2},
        {"scene": "other-fp"},
        {"upstream": ["b" * 64]},
        {"upstream": []},
        {"upstream": ["a" * 64, "b" * 64]},
    ],
)
def test_key_changes_with_config_stage_schema_scene_and_upstream(changed):
    assert _key(**changed) != _key()


@pytest.mark.parametrize(
    "noise",
    [
        {"paths": {"out": "/tmp/x"}},
        {"hydra": {"run": {"dir": "x"}}},
        {"tags": ["try-1"]},
        {"logging": {"every": 10}},
        {"progress": False},
        {"checkpoint_every": 250},
        {"output_dir": "/a"},
        {"cache_path": "/b"},
        {"lr": {"xyz": 1.6e-4, "mlp": 1.6e-4, "log_file": "x.txt"}},
    ],
)
def test_paths_tags_logging_and_hydra_never_enter_the_key(noise):
    merged = {**BASE_CFG, **noise}
    assert _key(cfg=merged) == _key()
    assert key_config(merged) == key_config(BASE_CFG)


def test_key_config_strips_at_any_depth_and_canonical_json_is_compact_and_sorted():
    cfg = {"a": 1, "nested": {"hydra": {"x": 1}, "b": [{"data_root": "/d", "c": 2}]}}
    assert key_config(cfg) == {"a": 1, "nested": {"b": [{"c": 2}]}}
    assert is_non_key_name("scene_dir") and not is_non_key_name("directions")
    text = canonical_json({"b": 1, "a": [1.0, 0.1, float("inf")]})  # 1.0 stays a float
    assert text == '{"a":[1.0,0.1,Infinity],"b":1}'


@pytest.mark.parametrize(
    ("cfg", "named"),
    [
        ({"k": {1, 2}}, ["relay", "config.k", "set"]),
        ({"k": object()}, ["config.k", "object"]),
        ({"sub": {3: "x"}}, ["key 3"]),
    ],
)
def test_values_without_a_stable_form_are_refused_in_one_line(cfg, named):
    with refused(InputError, *named):
        _key(cfg=cfg)
