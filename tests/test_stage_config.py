"""Stage settings: defaults parse, budgets validate, bad keys and values fail in one line."""

from __future__ import annotations

import importlib
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from refusals import refused
from relaygs.errors import InputError
from relaygs.model import BACKGROUND_DENSIFY, FOREGROUND_DENSIFY, DensityController, GaussianSet
from relaygs.stages import SPECS, StageSpec, step_budgets, validate_config
from relaygs.stages.decouple import DecoupleConfig
from relaygs.stages.deform import DeformConfig
from relaygs.stages.relay import RelayConfig
from relaygs.stages.train_settings import TrainSettings
from relaygs.stages.warmup import WarmupConfig
from relaygs.train import budgets


def test_each_stage_module_declares_the_spec_it_is_listed_under() -> None:
    for name, spec in SPECS.items():
        module = importlib.import_module(f"relaygs.stages.{name}")
        assert module.SPEC is spec and spec.run.__name__ == name
        assert set(spec.upstream) <= set(SPECS)


@pytest.mark.parametrize("version", ["1", 0, True])
def test_a_schema_version_that_is_no_integer_from_1_is_refused(version) -> None:
    # before: a stage left out of SCHEMA_VERSIONS was keyed as version 1 whatever its module
    # said, so a bump kept reusing stale artifacts
    with pytest.raises(InputError, match="'mine'"):
        StageSpec("mine", SPECS["warmup"].run, WarmupConfig, version)


def test_a_budget_section_that_is_no_stage_type_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # before: left out of BUDGETS without a word, so tests trained it at its paper steps
    (tmp_path / "budget").mkdir()
    (tmp_path / "budget" / "tiny.yaml").write_text("budget: {name: tiny}\nmine: {steps: 2}\n")
    monkeypatch.setattr(budgets, "config_dir", lambda: tmp_path)
    with pytest.raises(InputError, match=r"tiny.yaml: section\(s\) \['mine'\]"):
        budgets.load_budget("tiny", ("train", "warmup"))


def test_a_budget_over_another_keeps_its_settings_and_overrides_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "budget").mkdir()
    (tmp_path / "budget" / "base.yaml").write_text(
        "budget: {name: base}\nwarmup: {steps: 2, init_points: 7, densify: {densify_every: 3}}\n"
    )
    (tmp_path / "budget" / "long.yaml").write_text(
        "defaults: [base, _self_]\nbudget: {name: long}\nwarmup: {steps: 10, densify: {}}\n"
    )
    (tmp_path / "budget" / "bad.yaml").write_text("defaults: [_self_, base]\nwarmup: {}\n")
    monkeypatch.setattr(budgets, "config_dir", lambda: tmp_path)
    long = budgets.load_budget("long", ("train", "warmup"))
    assert long["warmup"] == {"steps": 10, "init_points": 7, "densify": {"densify_every": 3}}
    with pytest.raises(InputError, match=r"bad.yaml: defaults"):
        budgets.load_budget("bad", ("train", "warmup"))


def test_medium_is_small_at_more_steps() -> None:
    small, medium = step_budgets()["small"], step_budgets()["medium"]
    assert medium["relay"]["seed_points"] == small["relay"]["seed_points"]
    assert medium["deform"]["lr_fg"] == small["deform"]["lr_fg"]
    assert medium["deform"]["steps"] == 5 * small["deform"]["steps"]


def test_paper_defaults_and_partial_mappings_merged_over_them() -> None:
    section = DecoupleConfig.from_config({"lr": {"quats": 0.5}, "steps": 100})
    rates = section.learning_rates()
    assert rates.quats.init == 0.5
    assert rates.means.init == 2e-4  # kept from the default mapping
    # a decaying schedule without max_steps decays over the stage's own steps
    assert rates.means.max_steps == 100
    assert rates.extras["mask_logit"].init == section.mask_lr
    assert DecoupleConfig.from_config(None).steps == 3000
    assert DecoupleConfig.from_config({}).mask_init == 2.0
    relay = RelayConfig.from_config({})
    assert (relay.steps, relay.k, relay.p, relay.pseudo_views) == (14000, 16, 3, True)
    deform = DeformConfig.from_config({})
    assert (deform.steps, deform.isolate_fg_bg, deform.gamma) == (20000, True, True)
    assert (deform.plane_smoothness, deform.time_smoothness, deform.time_l1) == (2e-4, 1e-3, 1e-4)
    assert SPECS["warmup"].settings.from_config({}).steps == 3000
    train = TrainSettings.from_config({})
    assert (train.batch_views, train.ssim_weight) == (4, 0.2)
    plans = RelayConfig.from_config({}).plans()  # the foreground's, as the paper sets them
    assert set(plans) == {"fg"}  # background frozen by default
    assert plans["fg"].learning_rates.means.init == 1e-3
    assert plans["fg"].densify.grad_threshold == 1e-4
    background = DecoupleConfig.from_config({}).densify_settings()
    assert plans["fg"].densify.percent_dense == pytest.approx(0.1 * background.percent_dense)
    assert set(RelayConfig.from_config({"freeze_background": False}).plans()) == {"fg", "bg"}


@pytest.mark.parametrize("budget", sorted(step_budgets()))
@pytest.mark.parametrize("stage", sorted(SPECS))
def test_budgets_validate(budget: str, stage: str) -> None:
    validate_config(stage, step_budgets()[budget])


@pytest.mark.parametrize("config", [RelayConfig, DeformConfig])
def test_per_set_sections_start_from_the_papers_fg_and_bg_settings(config: type) -> None:
    section = config.from_config({"freeze_background": False} if config is RelayConfig else {})
    for name, preset in (("fg", FOREGROUND_DENSIFY), ("bg", BACKGROUND_DENSIFY)):
        until = min(preset.densify_until, section.steps)
        assert section.set_densify(name) == replace(preset, densify_until=until)
    assert section.set_densify("fg").grad_threshold != BACKGROUND_DENSIFY.grad_threshold
    decay = {"means": {"init": 1e-3, "final": 1e-5}}
    tuned = config.from_config({"densify_fg": {"grad_threshold": 3e-4}, "lr_fg": decay})
    assert tuned.set_densify("fg").grad_threshold == 3e-4
    assert tuned.set_densify("fg").percent_dense == FOREGROUND_DENSIFY.percent_dense
    assert tuned.set_rates("fg").for_param("means").max_steps == tuned.steps


DELAYED = {"init": 1e-3, "final": 1e-5, "delay_steps": 10}
INF, NAN = float("inf"), float("nan")


@pytest.mark.parametrize(
    ("stage", "section", "needle"),
    [
        ("decouple", {"bogus": 1}, "bogus"),
        ("decouple", {"steps": -1}, "decouple.steps"),
        ("decouple", {"steps": "many"}, "decouple.steps"),
        ("decouple", {"steps": True}, "decouple.steps"),
        ("decouple", {"mask_threshold": 1.5}, "decouple.mask_threshold"),
        ("decouple", {"lr": {"speed": 1.0}}, "decouple.lr"),
        ("decouple", {"lr": {"means": -1.0}}, "decouple.lr.means"),
        ("decouple", {"densify": {"densify_every": 0}}, "decouple.densify.densify_every"),
        ("decouple", {"densify": {"often": 3}}, "often"),
        ("relay", {"k": 0}, "relay.k"),
        ("relay", {"p": 0}, "relay.p"),
        ("relay", {"hull_seen": 1.5}, "relay.hull_seen"),
        ("deform", {"hull_weight": -1.0}, "deform.hull_weight"),
        ("deform", {"hull_coverage": INF}, "deform.hull_coverage"),
        ("deform", {"frame_patches": -1}, "deform.frame_patches"),
        ("deform", {"patch_opacity": 1.0}, "deform.patch_opacity"),
        ("relay", {"segments_per_step": 0}, "relay.segments_per_step"),
        ("relay", {"densify_fg": {"max_gaussians": 0}}, "relay.densify_fg.max_gaussians"),
        ("relay", {"freeze_background": False, "lr_bg": {"quats": -1.0}}, "relay.lr_bg.quats"),
        ("deform", {"steps": -5}, "deform.steps"),
        ("deform", {"color_affine": "maybe"}, "deform.color_affine"),
        ("deform", {"matmul_dtype": "float16"}, "deform.matmul_dtype"),
        ("deform", {"multires": []}, "deform.multires"),
        ("deform", {"multires": 2}, "deform.multires"),
        ("deform", [{"steps": 5}], "deform"),
        ("deform", {"lr_fg": {"means": -1.0}}, "deform.lr_fg.means"),
        ("deform", {"densify_bg": {"split_count": 1}}, "deform.densify_bg.split_count"),
        ("deform", {"lr_grid": {"init": 1.0, "final": 0.0}}, "deform.lr_grid.final"),
        ("replicate", {"k": -2}, "replicate.k"),
        # an infinite rate or weight would turn the first step's parameters into NaN
        ("decouple", {"lr": {"sh_dc": INF}}, "decouple.lr.sh_dc"),
        ("decouple", {"lr": {"means": {"init": INF, "final": 1.0}}}, "lr.means.init"),
        ("decouple", {"lr": {"means": {"init": 1.0, "final": INF}}}, "lr.means.final"),
        ("decouple", {"mask_lr": INF}, "decouple.mask_lr"),
        ("relay", {"lr_fg": {"means": INF}}, "relay.lr_fg.means"),
        ("deform", {"lr_mlp": {"init": INF, "final": 1e-5}}, "deform.lr_mlp.init"),
        ("deform", {"lr_gamma": INF}, "deform.lr_gamma"),
        ("deform", {"plane_smoothness": INF}, "deform.plane_smoothness"),
        ("decouple", {"lr": {"means": {**DELAYED, "delay_mult": INF}}}, "lr.means.delay_mult"),
        ("relay", {"lr_fg": {"means": {**DELAYED, "delay_mult": NAN}}}, "lr_fg.means.delay_mult"),
        ("deform", {"lr_grid": {**DELAYED, "delay_mult": -1.0}}, "deform.lr_grid.delay_mult"),
        ("deform", {"lr_mlp": {**DELAYED, "delay_steps": -1}}, "deform.lr_mlp.delay_steps"),
        ("warmup", {"init_opacity": 1.0}, "warmup.init_opacity"),
        # a mask logit that is not a finite float32 stops the training at step 1 (diverged)
        ("decouple", {"mask_init": NAN}, "decouple.mask_init"),
        ("decouple", {"mask_init": -INF}, "decouple.mask_init"),
        ("decouple", {"mask_init": 1e300}, "decouple.mask_init"),
        # learning rates of the wrong type: a traceback, or (a bool) silently the rate 1
        ("decouple", {"lr": {"quats": "abc"}}, "decouple.lr.quats"),
        ("decouple", {"lr": {"sh_dc": None}}, "decouple.lr.sh_dc"),
        ("decouple", {"lr": {"opacity_logits": True}}, "decouple.lr.opacity_logits"),
        ("warmup", {"lr": {"means": [1.0]}}, "warmup"),
        ("decouple", {"lr": {"means": {"init": "abc", "final": 1e-5}}}, "decouple.lr.means.init"),
        ("relay", {"lr_fg": {"means": {**DELAYED, "max_steps": 2.5}}}, "lr_fg.means.max_steps"),
        ("relay", {"lr_fg": {"means": {**DELAYED, "delay_steps": "x"}}}, "means.delay_steps"),
        ("relay", {"lr_fg": {"extras": "abc"}}, "relay.lr_fg.extras"),
        ("deform", {"lr_grid": {"init": None, "final": 1e-4}}, "deform.lr_grid.init"),
        ("deform", {"lr_mlp": {"init": 1e-3, "final": "abc"}}, "deform.lr_mlp.final"),
        ("deform", {"lr_mlp": {**DELAYED, "delay_mult": True}}, "deform.lr_mlp.delay_mult"),
        # density control: a reset to opacity 0 is a logit of -inf, an infinite divisor a
        # log-scale of -inf, a screen radius <= 0 prunes every Gaussian ever seen
        ("decouple", {"densify": {"reset_opacity": 0.0}}, "decouple.densify.reset_opacity"),
        ("deform", {"densify_fg": {"split_scale_divisor": INF}}, "split_scale_divisor"),
        ("warmup", {"densify": {"max_screen_radius": -1.0}}, "warmup.densify.max_screen_radius"),
        ("relay", {"densify_fg": {"max_screen_radius": NAN}}, "max_screen_radius"),
        # torch takes no size past int64: a traceback deep in the stage before
        ("relay", {"p": 10**20}, "relay.p: expected an int <= 9223372036854775807"),
        ("deform", {"width": -(10**20)}, "deform.width: expected an int <="),
        # infinite thresholds would train, then fail writing the artifact's JSON meta
        ("decouple", {"densify": {"grad_threshold": INF}}, "densify.grad_threshold"),
        ("relay", {"densify_fg": {"percent_dense": INF}}, "densify_fg.percent_dense"),
        ("deform", {"densify_bg": {"max_world_size": INF}}, "bg.max_world_size"),
        ("warmup", {"densify": {"max_screen_radius": INF}}, "max_screen_radius"),
        # the background's settings enter the relay key even while it is frozen (the default)
        ("relay", {"densify_bg": {"grad_treshold": 1.0}}, "relay.densify_bg"),
        ("relay", {"lr_bg": {"quats": -1.0}}, "relay.lr_bg.quats"),
    ],
)
def test_bad_section_values_name_the_key(stage: str, section: dict, needle: str) -> None:
    with refused(InputError, needle):
        validate_config(stage, {stage: section})


@pytest.mark.parametrize(
    ("cfg", "needle"),
    [
        ({"train": {"batch_views": 0}}, "train.batch_views"),
        ({"train": {"ssim_weight": 2.0}}, "train.ssim_weight"),
        ({"train": {"eps2d": -0.1}}, "train.eps2d"),
        ({"train": {"eps2d": float("inf")}}, "train.eps2d"),
        ({"train": {"antialiased": "sometimes"}}, "antialiased"),
        ({"train": {"device": "warp-drive"}}, "train.device"),
        ({"train": {"device": "meta"}}, "train.device: expected 'cpu', 'cuda'"),
        ({"train": {"wandb": True}}, "wandb"),
        ({"eval": {"frame_stride": 0}}, "eval.frame_stride"),
        ({"train": {"batch_views": 10**20}}, "train.batch_views: expected an int <= 9223372"),
    ],
)
def test_bad_shared_sections_or_stage_types_name_the_key(cfg: dict, needle: str) -> None:
    with refused(InputError, needle):
        validate_config("decouple", cfg)
    with refused(InputError, "unknown stage type 'stage4'"):
        validate_config("stage4", cfg)


def test_an_unusable_cuda_device_is_refused_where_the_stage_would_train() -> None:
    # No CUDA here: plain "cuda" is unusable; with GPUs, the index one past the last one.
    device = f"cuda:{torch.cuda.device_count()}" if torch.cuda.is_available() else "cuda"
    validate_config("decouple", {"train": {"device": device}})  # may be a Slurm node's GPU
    train = TrainSettings.from_config({"device": device})
    with refused(InputError, f"train.device: cannot use '{device}'"):
        train.torch_device()


def test_density_control_ends_before_a_stages_last_step() -> None:
    # before: at the paper's 3000 decouple steps the opacity reset every 3000 fell on the last
    # step, leaving relay a frozen, nearly transparent background; relay split on its last step
    relay, deform = RelayConfig.from_config({}), DeformConfig.from_config({})
    ends = {
        "decouple": DecoupleConfig.from_config({}).densify_settings(),
        "warmup": WarmupConfig.from_config({}).densify_settings(),
        "relay": relay.plans()["fg"].densify,
        "deform": deform.plans()["bg"].densify,  # 15000 < its 20000 steps: unchanged
    }
    until = {stage: settings.densify_until for stage, settings in ends.items()}
    assert until == {"decouple": 3000, "warmup": 3000, "relay": 14000, "deform": 15000}
    gaussians = GaussianSet.from_points(torch.rand(20, 3), torch.rand(20, 3))
    controller = DensityController(gaussians, ends["decouple"], 1.0)
    assert controller.step(3000) is None
    assert controller.step(2900) is not None


@pytest.mark.parametrize(
    ("downscale", "width", "early", "expected"),
    [
        (None, 640, True, 2),  # Panoptic size: decouple and relay at half resolution
        (None, 640, False, 1),  # deform (and the warm-up) at full resolution
        (None, 160, True, 1),  # the default synthetic scene stays at full resolution
        (3, 160, False, 3),  # an explicit factor applies to every stage
    ],
)
def test_training_resolution_rule(downscale, width: int, early: bool, expected: int) -> None:
    train = TrainSettings.from_config({"downscale": downscale})
    assert train.downscale_for(width, early_stage=early) == expected
