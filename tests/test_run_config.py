"""The config tree: defaults, groups, experiments, budgets and launchers compose as documented."""

import pytest
from hydra import compose, initialize_config_dir
from hydra.types import RunMode
from omegaconf import OmegaConf

from relaygs import paths
from relaygs.app.plan import scale_steps
from relaygs.model import paper_schedule
from relaygs.stages import SPECS, EvalSettings, TrainSettings, step_budgets
from relaygs.stages.config import json_ready

SUBMITIT = "hydra_plugins.hydra_submitit_launcher.submitit_launcher"
JOBLIB = "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher"
SWEEPS = {
    "ablation_k": {"relay.k": "8,16,32,64,128"},
    "ablation_segments": {"relay.k": "4,8,16", "relay.segments": "uniform,adaptive"},
    "ablation_components": {
        "+component": "full,no_copies,no_stage2,no_pseudo_views,no_isolation,no_gamma"
    },
    "baseline": {"pipeline": "relaygs,4dgs"},
    "budget": {"pipeline": "relaygs,4dgs", "budget.multiplier": "0.25,0.5,1.0,2.0"},
}
EXPERIMENTS = (*SWEEPS, "smoke")  # the sweeps, and the one experiment that runs one job


@pytest.fixture(scope="module")
def composer():
    """compose(overrides, with_hydra=False) on the repository's conf/ (initialised once)."""
    with initialize_config_dir(config_dir=str(paths.config_dir()), version_base="1.3"):
        yield lambda overrides=(), with_hydra=False: compose(
            "config", overrides=list(overrides), return_hydra_config=with_hydra
        )


def test_defaults_are_the_main_job(composer):
    cfg = composer()
    assert cfg.pipeline.name == "relaygs"
    scene = cfg.scene
    assert (scene.preset, scene.width, scene.height, scene.frames) == ("juggle", 160, 90, 64)
    assert cfg.budget.name == "small" and cfg.budget.multiplier == 1.0
    assert cfg.relay.k == cfg.replicate.k == 1 and cfg.relay.pseudo_views is True
    assert cfg.deform.gamma is True and cfg.deform.isolate_fg_bg is True
    assert cfg.seed == 0 and cfg.artifacts.on_corrupt.name == "rebuild"
    assert cfg.artifacts.root == "outputs/artifacts"


@pytest.mark.parametrize(("budget", "k"), [("small", 1), ("paper", 16), ("smoke", 16)])
def test_segment_length_follows_the_budget_unless_set(composer, budget, k):
    """`small` relays one copy per frame (few deform steps); the others keep the paper's k = 16."""
    assert composer([f"budget={budget}"]).relay.k == k
    cfg = composer([f"budget={budget}", "relay.k=8"])
    assert cfg.relay.k == cfg.replicate.k == 8  # replicate uses the relay segment length


def test_run_and_sweep_dirs_are_unique_to_the_microsecond_and_avoid_runtime_cwd(composer):
    hydra_cfg = OmegaConf.to_container(composer(with_hydra=True).hydra, resolve=False)
    for key in ("run", "sweep"):
        assert "%f" in hydra_cfg[key]["dir"]
        assert "runtime.cwd" not in str(hydra_cfg[key])
    assert "SweepSummary" in hydra_cfg["callbacks"]["sweep_summary"]["_target_"]


def test_paper_density_schedule_is_in_the_config_so_the_multiplier_scales_it(composer):
    # before: every `densify*` section was {} (the presets' 500/100/15000/3000 from code), so
    # `budget.multiplier` scaled the paper budget's steps but not its density schedule
    cfg = OmegaConf.to_container(composer(["budget=paper"]), resolve=True)
    doubled = {key: 2 * value for key, value in paper_schedule().items()}
    sections = [
        (stage, name)
        for stage in ("decouple", "warmup", "relay", "deform")
        for name in cfg[stage]
        if name.startswith("densify")
    ]
    assert len(sections) == 6
    for stage, name in sections:
        scaled = scale_steps(cfg[stage][name], 2.0, cfg["budget"]["scaled_keys"])
        assert scaled == doubled, (stage, name)


def test_budgets_order_by_cost(composer):
    cfg = composer(["budget=paper"])  # the paper's step counts
    assert (cfg.decouple.steps, cfg.relay.steps, cfg.deform.steps) == (3000, 14000, 20000)
    steps = {
        name: [composer([f"budget={name}"])[stage].steps for stage in ("decouple", "deform")]
        for name in ("smoke", "small", "paper")
    }
    assert all(
        a < b < c for a, b, c in zip(steps["smoke"], steps["small"], steps["paper"], strict=True)
    )


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_experiment_composes_with_smoke_budget_and_another_scene(composer, name):
    cfg = composer([f"+experiment={name}", "budget=smoke", "scene=court"], with_hydra=True)
    assert cfg.budget.name == "smoke"
    assert cfg.scene.preset == "court"
    assert cfg.experiment_name == name
    if name in SWEEPS:
        assert cfg.hydra.mode == RunMode.MULTIRUN
        assert dict(cfg.hydra.sweeper.params) == SWEEPS[name]
    else:
        assert cfg.hydra.mode != RunMode.MULTIRUN


def test_smoke_experiment_is_a_tiny_scene_at_smoke_budget(composer):
    cfg = composer(["+experiment=smoke"])
    assert cfg.budget.name == "smoke"
    assert cfg.scene.width * cfg.scene.height * cfg.scene.frames <= 48 * 27 * 8


@pytest.mark.parametrize(
    ("component", "changes"),
    [
        ("full", {}),
        ("no_copies", {"pipeline.name": "no_copies"}),
        ("no_stage2", {"pipeline.name": "no_stage2"}),
        ("no_pseudo_views", {"relay.pseudo_views": False}),
        ("no_isolation", {"deform.isolate_fg_bg": False}),
        ("no_gamma", {"deform.gamma": False}),
    ],
)
def test_components_change_exactly_their_setting(composer, component, changes):
    cfg = composer(["+experiment=ablation_components", f"+component={component}"])
    default = composer()
    assert cfg.variant == component
    keys = ("pipeline.name", "relay.pseudo_views", "deform.isolate_fg_bg", "deform.gamma")
    changed = {
        key: OmegaConf.select(cfg, key)
        for key in keys
        if OmegaConf.select(cfg, key) != OmegaConf.select(default, key)
    }
    assert changed == changes


def test_variant_labels_follow_the_swept_values(composer):
    assert composer(["+experiment=ablation_k", "relay.k=32"]).variant == "k32"
    cfg = composer(["+experiment=ablation_segments", "relay.k=8", "relay.segments=adaptive"])
    assert cfg.variant == "k8_adaptive"
    cfg = composer(["+experiment=budget", "pipeline=4dgs", "budget.multiplier=0.5"])
    assert cfg.variant == "4dgs_x0.5"
    assert composer(["+experiment=baseline", "pipeline=4dgs"]).variant == "4dgs"


@pytest.mark.parametrize(
    ("launcher", "plugin", "checks"),
    [
        (
            "slurm",
            "hydra_plugins.hydra_submitit_launcher",
            {"_target_": f"{SUBMITIT}.SlurmLauncher", "timeout_min": 240, "partition": None},
        ),
        ("submitit_slurm", "hydra_plugins.hydra_submitit_launcher", {"timeout_min": 60}),
        ("joblib", "hydra_plugins.hydra_joblib_launcher", {"_target_": JOBLIB, "n_jobs": -1}),
    ],
)
def test_launchers_compose_with_a_sweep(composer, launcher, plugin, checks):
    pytest.importorskip(plugin)
    cfg = composer([f"hydra/launcher={launcher}", "+experiment=ablation_k"], with_hydra=True)
    assert {key: cfg.hydra.launcher[key] for key in checks} == checks
    assert cfg.hydra.sweeper.params["relay.k"] == "8,16,32,64,128"


def test_stage_groups_hold_exactly_the_stage_defaults(composer):
    cfg = OmegaConf.to_container(composer(["budget=paper"]), resolve=True)
    for stage, spec in SPECS.items():
        assert cfg[stage] == json_ready(spec.settings()), stage
    assert cfg["train"] == json_ready(TrainSettings())
    assert cfg["eval"] == json_ready(EvalSettings())


@pytest.mark.parametrize("budget", ["paper", "medium", "small", "smoke"])
def test_budget_files_set_the_stages_budgets(composer, budget):
    cfg = OmegaConf.to_container(composer([f"budget={budget}"]), resolve=True)
    for section, values in step_budgets()[budget].items():
        assert _with_only_their_keys(cfg[section], values) == values, section


def _with_only_their_keys(composed, budget_values):
    """The composed config cut to the keys the budget file sets, at every depth: a budget may
    set one rate of a set's rates and keep the stage's others."""
    if not isinstance(budget_values, dict):
        return composed
    return {key: _with_only_their_keys(composed[key], budget_values[key]) for key in budget_values}
