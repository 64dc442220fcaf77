"""The five experiments at `budget=smoke` on a tiny scene, end to end with the real stages, one
process per command as a user runs them. Marked `sweep`: deselect with `-m "not sweep"`."""

import json
import math
import subprocess
import time

import pandas as pd
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.hparams import plugin_data_pb2

from relaygs.commands.bench_sweeps import EXPERIMENTS, command

pytestmark = pytest.mark.sweep

HANG_GUARD_S = 1800.0  # a command this slow is stuck, not slow (speed is not asserted here)
# Fewer jobs than the experiments' own sweeps, where the test needs no more: a command line's
# sweep of a key replaces the experiment's, so the launchers and the summaries run as they do.
BUDGET_MULTIPLIERS = "budget.multiplier=0.5,1.0"
TWO_K = "relay.k=8,16"


def _launch(outputs, name, *overrides):
    done = subprocess.run(
        command(name, outputs, *overrides), capture_output=True, text=True, timeout=HANG_GUARD_S
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def _newest_sweep(outputs):
    return max((outputs / "sweeps").iterdir(), key=lambda path: path.stat().st_mtime)


def _artifact_counts(outputs):
    root = outputs / "artifacts"
    return {
        stage.name: len([key for key in stage.iterdir() if (key / "COMPLETE").is_file()])
        for stage in root.iterdir()
        if stage.is_dir() and not stage.name.startswith(".")
    }


@pytest.fixture(scope="module")
def experiments(tmp_path_factory):
    """Run the five experiments in order; record each one's sweep folder, store counts and
    output."""
    outputs = tmp_path_factory.mktemp("outputs")
    runs = {}
    started = time.perf_counter()
    for name in EXPERIMENTS:
        done = _launch(outputs, name, *([BUDGET_MULTIPLIERS] if name == "budget" else []))
        folder = _newest_sweep(outputs) if name != "smoke" else None
        runs[name] = {"sweep": folder, "counts": _artifact_counts(outputs), "out": done.stdout}
    runs["elapsed_s"] = time.perf_counter() - started
    runs["outputs"] = outputs
    return runs


def _summary(experiments, name):
    return pd.read_csv(experiments[name]["sweep"] / "summary.csv")


def test_smoke_is_a_single_run_with_a_result_and_every_sweep_writes_its_summary(experiments):
    print(f"five smoke experiments: {experiments['elapsed_s']:.1f} s")
    for name in EXPERIMENTS[1:]:
        assert (experiments[name]["sweep"] / "summary.md").is_file(), name
    (result_path,) = (experiments["outputs"] / "runs").glob("*/result.json")
    result = json.loads(result_path.read_text())
    assert result["variant"] == "smoke" and math.isfinite(result["psnr"])
    assert result["num_gaussians"] > 0 and result["storage_mb"] > 0


def test_ablation_k_on_8_frames_is_one_segment_for_every_k_and_reuses_the_smoke_run(
    experiments,
):
    table = _summary(experiments, "ablation_k")
    assert list(table.variant) == ["k8", "k16", "k32", "k64", "k128"]
    assert list(table["relay.k"]) == [8, 16, 32, 64, 128]  # as swept, though all run k = 8
    assert table.psnr.notna().all() and table.output_key.nunique() == 1
    counts = experiments["ablation_k"]["counts"]
    assert (counts["decouple"], counts["relay"], counts["deform"]) == (1, 1, 1)
    assert (table.cache_hits == 3).all()  # the smoke run (k = 16 on 8 frames) built them
    assert counts["eval"] == 1 and (table.eval_s_computed == 0).all()  # and evaluated it
    lines = experiments["ablation_k"]["out"].splitlines()  # one job at a time: no job labels
    assert sum(line.startswith("[decouple] reused decouple ") for line in lines) == 5


def test_components_build_each_distinct_upstream_once(experiments):
    table = _summary(experiments, "ablation_components")
    components = "full no_copies no_stage2 no_pseudo_views no_isolation no_gamma"
    assert list(table.variant) == components.split()
    before = experiments["ablation_k"]["counts"]
    after = experiments["ablation_components"]["counts"]
    new = {stage: after.get(stage, 0) - before.get(stage, 0) for stage in after}
    assert new == {"decouple": 0, "relay": 1, "replicate": 1, "deform": 5, "eval": 5}
    assert table.loc[table.variant == "full", "delta_psnr"].item() == 0.0
    # every job logs the same hparam keys
    key_sets = []
    for result in sorted(experiments["ablation_components"]["sweep"].glob("*/result.json")):
        events = EventAccumulator(str(result.parent))
        events.Reload()
        content = events.PluginTagToContent("hparams")["_hparams_/session_start_info"]
        data = plugin_data_pb2.HParamsPluginData.FromString(content)
        key_sets.append(set(data.session_start_info.hparams))
        assert "result/psnr" in events.Tags()["scalars"]
    assert len(key_sets) == 6 and all(keys == key_sets[0] for keys in key_sets)


def test_baseline_and_budget_compare_relaygs_with_4dgs_on_the_same_scene(experiments):
    table = _summary(experiments, "baseline")
    assert list(table.variant) == ["relaygs", "4dgs"]
    assert table.scene.nunique() == 1 and table.seed.nunique() == 1
    assert list(table.cache_hits) == [3, 0]
    assert table["deform.gamma"].tolist() == [True, False]
    # the budget sweep: both pipelines over the multipliers
    table = _summary(experiments, "budget")
    assert len(table) == 4
    assert sorted(set(table["budget.multiplier"])) == [0.5, 1.0]
    assert set(table.pipeline) == {"relaygs", "4dgs"}
    unscaled = table[table["budget.multiplier"] == 1.0]
    assert (unscaled.train_s_computed == 0).all()  # built by the baseline sweep already
    assert (experiments["budget"]["sweep"] / "pareto.png").is_file()


def test_parallel_jobs_share_the_store_and_build_decouple_once(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    done = _launch(
        tmp_path, "ablation_k", TWO_K, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"
    )
    counts = _artifact_counts(tmp_path)
    assert (counts["decouple"], counts["relay"]) == (1, 1)  # every k >= 8 frames: one segment
    sweep = _newest_sweep(tmp_path)
    assert len(pd.read_csv(sweep / "summary.csv")) == 2
    # the jobs print side by side: each status line names its job's folder
    jobs = {result.parent.name for result in sweep.glob("*/result.json")}
    status = [line for line in done.stdout.splitlines() if "] [decouple] " in line]
    assert {line.split("]")[0].lstrip("[") for line in status} == jobs
    assert sum(" built decouple " in line for line in status) == 1
    # and so does each job's results table and outputs block, printed whole
    lines = done.stdout.splitlines()
    blocks = [
        (line.removesuffix("outputs:"), lines[i + 1])
        for i, line in enumerate(lines[:-1])
        if line.endswith("] outputs:")
    ]
    assert {label for label, _ in blocks} == {f"[{job}] " for job in jobs}
    assert all(after.startswith(f"{label}  result ") for label, after in blocks)


def test_a_sweep_through_submitit_gives_the_basic_launchers_summary(experiments, tmp_path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")  # the slurm extra
    # submitit's local executor is the Slurm launcher's code path: each job pickled into a
    # process of its own, the jobs sharing one store and its locks, the results gathered back
    _launch(tmp_path, "ablation_k", TWO_K, "hydra/launcher=submitit_local")
    counts = _artifact_counts(tmp_path)
    assert counts["decouple"] == 1 and counts["relay"] == 1  # every k >= 8 frames: one segment
    submitit = pd.read_csv(_newest_sweep(tmp_path) / "summary.csv")
    basic = _summary(experiments, "ablation_k")
    shared = ["variant", "relay.k", "psnr", "ssim", "fg_psnr", "num_gaussians", "output_key"]
    pd.testing.assert_frame_equal(submitit[shared], basic[shared].head(2))
    assert (submitit.status == "ok").all()
