"""Run plans: per-node stage configs (overrides, budget scaling), artifact-key sharing, and
pipeline files' per-node `overrides`."""

import copy

import pytest
from omegaconf import OmegaConf

from fake_stages import STAGE_TYPES, compose_config, pipeline_section, validate_config, with_values
from refusals import refused
from relaygs.app.plan import merge_overrides, plan_run, scale_steps
from relaygs.errors import InputError
from relaygs.pipeline import artifact_key, key_config, load_pipeline
from relaygs.pipeline import spec as spec_module


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    cfg = compose_config([], tmp_path_factory.mktemp("outputs"))
    return OmegaConf.to_container(cfg, resolve=True)


def _plan(config, **changes):
    return plan_run(with_values(config, **changes), STAGE_TYPES, validate_config)


def _keys(plan):
    """Each node's artifact key, chained through its upstreams as the runner does."""
    keys = {}
    for node in plan.pipeline.topological_order():
        cfg = key_config(plan.config_for(node))
        upstream = [keys[name] for name in node.upstream]
        keys[node.name] = artifact_key(node.stage, 1, cfg, "scene", upstream)
    return keys


def test_stage_configs_hold_only_seed_train_and_the_stage_section(config):
    plan = _plan(config)
    for node in plan.pipeline.nodes.values():
        stage_cfg = plan.config_for(node)
        assert set(stage_cfg) == {"seed", "train", node.stage}
        assert stage_cfg[node.stage] == config[node.stage]


@pytest.mark.parametrize(
    ("changes", "rekeyed"),
    [
        ({"relay__k": 32}, {"relay", "deform"}),
        ({"deform__gamma": False}, {"deform"}),  # decouple and relay are shared
        ({"train__checkpoint_every": 7}, set()),
        ({"tensorboard__hparams": "all", "tensorboard__preview_frames": 9}, set()),
        ({"train__progress": False}, set()),
    ],
)
def test_a_setting_changes_the_keys_of_the_nodes_it_reaches_only(config, changes, rekeyed):
    plain, changed = _keys(_plan(config)), _keys(_plan(config, **changes))
    assert {node for node in plain if plain[node] != changed[node]} == rekeyed


def test_logging_settings_reach_the_plan(config):
    plain = _plan(config)
    logged = _plan(config, tensorboard__hparams="all", tensorboard__preview_frames=9)
    assert (plain.hparams, logged.hparams, logged.preview_frames) == ("swept", "all", 9)
    assert plain.progress and not _plan(config, train__progress=False).progress


def test_pipeline_overrides_pin_the_4dgs_deform_settings(config):
    plan = _plan(config, pipeline=pipeline_section("4dgs"), deform__gamma=True)
    deform = plan.config_for(plan.pipeline.nodes["deform"])["deform"]
    assert (deform["gamma"], deform["isolate_fg_bg"]) == (False, False)
    assert config["deform"]["gamma"] is True  # the input is not modified


def test_budget_multiplier_scales_steps_of_every_node(config):
    plan = _plan(config, budget__multiplier=0.25)
    for node in plan.pipeline.nodes.values():
        steps = config[node.stage]["steps"]
        assert plan.config_for(node)[node.stage]["steps"] == max(1, round(steps * 0.25))


def test_scale_steps_scales_named_counts_at_any_depth_and_keeps_them_positive():
    section = {"steps": 3, "densify": {"until": 100, "every": 0}, "k": 16, "flag": True}
    assert scale_steps(section, 0.1, ["steps", "until", "every", "flag"]) == {
        "steps": 1,
        "densify": {"until": 10, "every": 0},
        "k": 16,
        "flag": True,
    }
    assert scale_steps({"steps": 0}, 2.0, ["steps"]) == {"steps": 0}
    assert scale_steps({"steps": -4}, 2.0, ["steps"]) == {"steps": -4}
    # a finite multiplier whose product is not (1e307 × 20) failed in round() with a traceback
    with refused(InputError, "budget.multiplier"):
        scale_steps({"densify": {"densify_every": 20}}, 1e307, ["densify_every"])


def test_merge_overrides_is_deep_and_rejects_unknown_settings():
    section = {"a": 1, "nested": {"x": 1, "y": 2}}
    merged = merge_overrides(section, {"nested": {"y": 5}}, "p.yaml: node 'n' overrides")
    assert merged == {"a": 1, "nested": {"x": 1, "y": 5}}
    assert section["nested"]["y"] == 2
    with refused(InputError, "p.yaml", "overrides.nested", "'z'"):
        merge_overrides(section, {"nested": {"z": 0}}, "p.yaml: node 'n' overrides")


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"budget__multiplier": 0}, ["budget.multiplier"]),
        ({"budget__multiplier": float("nan")}, ["budget.multiplier"]),
        ({"budget__scaled_keys": "steps"}, ["budget.scaled_keys"]),
        ({"budget__scaled_keys": ["steps", 3]}, ["budget.scaled_keys", "3"]),
        # a misspelt name would leave the steps it meant unscaled
        ({"budget__scaled_keys": ["stpes"]}, ["budget.scaled_keys", "'stpes'"]),
        ({"relay__k": -2}, ["relay.k"]),
        ({"deform__steps": -1}, ["deform.steps"]),
        ({"warmup__steps": -1, "pipeline": pipeline_section("4dgs")}, ["warmup.steps"]),
        ({"scene__preset": "mars"}, ["scene.preset", "'mars'"]),
        ({"scene__name": ["a"]}, ["scene.name"]),
        ({"scene__width": 0}, ["scene.width"]),
        # generated, it would be refused by the loader: refused before anything is generated
        ({"scene__height": 3}, ["scene.height", "3"]),
        ({"scene__effects": ["wind"]}, ["scene.effects", "'wind'"]),
        ({"scene__loader": {"zoom": 2}}, ["scene.loader", "'zoom'"]),
        ({"tensorboard__preview_frames": -1}, ["tensorboard.preview_frames"]),
        ({"threads": 0}, ["threads"]),
        # a sweep names each job's folder <job>_<variant>: a separator would put it elsewhere
        ({"variant": "a/b"}, ["variant", "'a/b'"]),
        ({"variant": ["a"]}, ["variant"]),
        # an experiment file's `budget: smoke` replaces the group's section with a value
        ({"budget": "smoke"}, ["budget", "'smoke'"]),
        # an experiment file without `# @package _global_` puts its settings under `experiment`
        ({"experiment": {"seed": 3}}, ["top level", "'experiment'"]),
    ],
)
def test_bad_values_are_one_line_errors_naming_the_field(config, changes, named):
    with refused(InputError, *named):
        _plan(config, **changes)


def test_unused_stage_sections_are_not_validated(config):
    plan = _plan(config, warmup__steps=-1)  # the relaygs pipeline has no warm-up
    assert "warmup" not in {node.stage for node in plan.pipeline.nodes.values()}


def test_pipeline_files_parse_per_node_overrides(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text(
        "nodes:\n"
        "  a: {stage: decouple}\n"
        "  b: {stage: deform, upstream: [a], overrides: {gamma: false, lr: {init: 2}}}\n"
    )
    pipeline = load_pipeline(path)
    assert pipeline.nodes["a"].overrides == {}
    assert pipeline.nodes["b"].overrides == {"gamma": False, "lr": {"init": 2}}
    assert load_pipeline("4dgs").nodes["deform"].overrides == {
        "isolate_fg_bg": False,
        "gamma": False,
    }


@pytest.mark.parametrize("value", ["[1, 2]", "7", "{1: x}"])
def test_pipeline_overrides_must_be_a_mapping_of_names(tmp_path, value):
    path = tmp_path / "p.yaml"
    path.write_text(f"nodes:\n  a: {{stage: decouple, overrides: {value}}}\n")
    with refused(InputError, str(path), "'overrides'"):
        load_pipeline(path)


@pytest.mark.parametrize(
    ("pipeline", "named"),
    [
        ({}, "pipeline.name"),
        ({"name": None}, "pipeline.name"),
        ({"name": ""}, "pipeline.name"),
        ({"name": True}, "pipeline.name"),
        ("4dgs", "'4dgs'"),
    ],
)
def test_a_pipeline_choice_without_a_name_is_one_line(config, pipeline, named):
    # before: KeyError 'name' from a conf/pipeline/<name>.yaml without `name: <name>`
    config = {**copy.deepcopy(config), "pipeline": pipeline}
    with refused(InputError, named):
        plan_run(config, STAGE_TYPES, validate_config)


def test_a_pipeline_name_yaml_reads_as_a_number_names_its_file(config, tmp_path, monkeypatch):
    # `name: 2024` in conf/pipeline/2024.yaml is an integer once YAML has read it
    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "2024.yaml").write_text("name: 2024\nnodes: {w: {stage: warmup}}\n")
    monkeypatch.setattr(spec_module, "config_dir", lambda: tmp_path)
    section = {"name": 2024, "nodes": {"w": {"stage": "warmup"}}}
    assert _plan(config, pipeline=section).pipeline.name == "2024"


def test_nodes_that_differ_from_the_pipelines_file_are_refused(config):
    # `pipeline.name=4dgs` alone would otherwise run relaygs's nodes labelled 4dgs
    for changed in ({"name": "4dgs"}, {"nodes": {"w": {"stage": "warmup"}}}):
        bad = {**copy.deepcopy(config), "pipeline": {**config["pipeline"], **changed}}
        with refused(InputError, "pipeline", "conf/pipeline/"):
            plan_run(bad, STAGE_TYPES, validate_config)


def test_a_pipeline_whose_stage_does_not_read_its_upstream_fails_in_the_plan(config, tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("nodes:\n  w: {stage: warmup}\n  r: {stage: relay, upstream: [w]}\n")
    config = {**copy.deepcopy(config), "pipeline": {"name": str(path)}}
    plan_run(config, STAGE_TYPES, validate_config)  # the stage would refuse it once w trained
    with refused(InputError, str(path), "'r'", "'relay'"):
        plan_run(config, STAGE_TYPES, validate_config, {"relay": ("decouple",)})
