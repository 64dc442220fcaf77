"""The job function end to end on fake stages: result.json, shared artifacts, TensorBoard."""

import dataclasses
import errno
import json
import os
import re

import pytest
import torch
from omegaconf import OmegaConf
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from conftest import WriteRecorder
from fake_stages import TINY_SCENE, FakeStages, compose_config, pipeline_section, with_values
from refusals import refused
from relaygs import errors
from relaygs.app import task as task_module
from relaygs.app.captions import CAPTION_HEIGHT
from relaygs.app.evaluation import evaluation_config
from relaygs.app.hparams import flatten_config
from relaygs.app.result import NO_TEST_VIEWS, RESULT_FILE, format_summary, write_result
from relaygs.app.suite import load_stage_suite
from relaygs.app.sweep_axes import SweepAxes
from relaygs.app.task import run_task
from relaygs.app.tensorboard import TensorBoardLog, training_tag
from relaygs.errors import InputError
from relaygs.per_view import PER_VIEW, PER_VIEW_FILE, read_per_view
from relaygs.pipeline import ArtifactStore, CorruptArtifactError
from relaygs.splat import default_backend, use_backend

REQUIRED_FIELDS = {
    "pipeline",
    "scene",
    "seed",
    "psnr",
    "ssim",
    "fg_psnr",
    "train_s_total",
    "train_s_computed",
    "storage_mb",
    "render_fps",
    "num_gaussians",
    "cache_hits",
}


@pytest.fixture(scope="module")
def base_config(tmp_path_factory):
    """The default config with a tiny scene and every output under one temp folder."""
    outputs = tmp_path_factory.mktemp("outputs")
    cfg = compose_config([*TINY_SCENE, "budget=smoke"], outputs)
    return OmegaConf.to_container(cfg, resolve=True)


def _run(config, run_dir, fakes, overrides=(), label=None, job=None):
    """Run with a store beside the run dir (runs in one test share it, tests do not)."""
    config = with_values(config, artifacts__root=str(run_dir.parent / "artifacts"))
    return run_task(
        config,
        run_dir=run_dir,
        original_cwd=run_dir,
        overrides=list(overrides),
        job=job,
        label=label,
        suite=fakes.suite(),
    )


def test_a_run_writes_a_flat_result_with_every_required_field(base_config, tmp_path, capsys):
    fakes = FakeStages()
    overrides = [
        "relay.k=8",
        "+component=full",
        "budget=smoke",
        "scene.loader.test_cameras=[0,2]",
        "paths.outputs=/x",
        "hydra.verbose=true",
    ]
    config = with_values(base_config, scene__loader__test_cameras=[0, 2])
    result = _run(config, tmp_path / "run", fakes, overrides=overrides)
    written = json.loads((tmp_path / "run" / RESULT_FILE).read_text())
    assert written == result
    assert set(written) >= REQUIRED_FIELDS
    assert all(not isinstance(value, dict | list) for value in written.values())
    assert (written["pipeline"], written["scene"], written["seed"]) == ("relaygs", "juggle", 0)
    assert written["relay.k"] == base_config["relay"]["k"]
    assert written["component"] == "full"
    assert written["budget.name"] == "smoke" and "budget" not in written  # one column, not two
    assert written["scene.loader.test_cameras"] == "[0, 2]"  # a list as its JSON text
    assert not any(key.startswith(("paths", "hydra")) for key in written)
    assert written["storage_mb"] > 0
    assert written["train_s_total"] >= written["train_s_computed"] > 0
    assert written["job_s"] > written["train_s_computed"]
    assert written["eval_frames"] == 2  # smoke evaluates every 2nd of 3 frames
    out = capsys.readouterr().out
    assert "PSNR" in out and str(tmp_path / "run" / RESULT_FILE) in out
    store = tmp_path / "artifacts"
    render = f"relaygs.artifacts --root {store} render {written['output_key'][:16]} --scene /"
    assert render in out


def test_runs_sharing_a_store_reuse_its_stages_and_evaluations(base_config, tmp_path, capsys):
    # nodes named other than their stage types: a reused stage is noted under its type
    pipeline = tmp_path / "renamed.yaml"
    pipeline.write_text(
        "nodes:\n  first: {stage: decouple}\n  second: {stage: relay, upstream: [first]}\n"
        "  model: {stage: deform, upstream: [second]}\n"
    )
    renamed = with_values(base_config, pipeline__name=str(pipeline))
    fakes = FakeStages(notes={"decouple": ["decouple marked no Gaussian as foreground"]})
    note = "note: [first] decouple marked no Gaussian as foreground"
    first = _run(with_values(renamed, relay__k=8), tmp_path / "a", fakes)
    (stored,) = (p for p in (tmp_path / "artifacts" / "decouple").iterdir() if p.is_dir())
    out, err = capsys.readouterr()
    path = tmp_path / "a" / PER_VIEW_FILE
    assert f"per view     {path}" in out and err.count(note) == 1
    second = _run(with_values(renamed, relay__k=32), tmp_path / "b", fakes)
    out, err = capsys.readouterr()
    assert "reused decouple artifact" in out and err.count(note) == 1  # said by every run
    again = _run(with_values(renamed, relay__k=32), tmp_path / "c", fakes)
    assert (fakes.ran("decouple"), fakes.ran("relay"), fakes.ran("deform")) == (1, 2, 2)
    assert (first["cache_hits"], second["cache_hits"], again["cache_hits"]) == (0, 1, 3)
    assert first["notes"] == again["notes"] == note.removeprefix("note: ")
    assert "notes" not in _run(base_config, tmp_path / "quiet" / "d", FakeStages())  # own store
    assert first["psnr"] != second["psnr"]
    # an evaluated model is not evaluated again: its metrics and per-view records are read back
    assert fakes.evaluations == 2 and "[eval] reused evaluation" in capsys.readouterr().out
    assert (again["train_s_computed"], again["eval_s_computed"]) == (0, 0.0)
    assert second["eval_s_computed"] == second["eval_s_total"]
    for name in ("train_s_total", "eval_s_total", "psnr", "eval_frames"):
        assert again[name] == pytest.approx(second[name]), name
    records = read_per_view(tmp_path / "b" / PER_VIEW_FILE)
    assert read_per_view(tmp_path / "c" / PER_VIEW_FILE) == records
    assert [(r["frame"], r["camera"]) for r in records] == [(0, 0), (0, 7), (2, 0), (2, 7)]
    assert PER_VIEW not in first  # the result stays flat
    # another frame stride is another evaluation of the same model
    _run(with_values(renamed, relay__k=32, eval__frame_stride=1), tmp_path / "e", fakes)
    assert fakes.evaluations == 3 and fakes.ran("deform") == 2
    # a result names the images it was scored on: another model, the same test images
    halved = _run(with_values(base_config, scene__loader__downscale=2), tmp_path / "f", fakes)
    held_out = _run(
        with_values(base_config, scene__loader__test_cameras=[2]), tmp_path / "g", fakes
    )
    assert len(first["test_set"]) == 12 and first["test_set"] == second["test_set"]
    assert len({first["test_set"], halved["test_set"], held_out["test_set"]}) == 3
    # TensorBoard: the built run's curves, previews, per-frame means and hparams
    assert fakes.sinks == []  # the sink is removed after each run
    built = EventAccumulator(str(tmp_path / "a"), size_guidance={"scalars": 0, "images": 0})
    built.Reload()
    tags = built.Tags()
    stages = {f"train/{stage}/loss" for stage in ("decouple", "relay", "deform")}
    assert stages | {"result/psnr"} <= set(tags["scalars"])
    assert {"eval/render_vs_truth", "train/deform/render"} <= set(tags["images"])
    (preview, *_) = built.Images("eval/render_vs_truth")
    # render, truth and error of 16×9 views, enlarged 18× (to >= 160 rows) under their captions
    assert (preview.width, preview.height) == (3 * 16 * 18, 9 * 18 + CAPTION_HEIGHT)
    plugins = built.PluginTagToContent("hparams")
    assert "_hparams_/experiment" in plugins and "_hparams_/session_start_info" in plugins
    # the fake's two cameras score psnr + f and psnr + 2f at frame f: their mean is psnr + 1.5 f
    logged = [(e.step, e.value) for e in built.Scalars("eval/psnr_by_frame")]
    assert logged == [(0, pytest.approx(first["psnr"])), (2, pytest.approx(first["psnr"] + 3))]
    assert "eval/fg_psnr_by_frame" not in tags["scalars"]  # no value at any frame
    # a job that reuses stages notes them instead of replaying their curves
    reused = EventAccumulator(str(tmp_path / "b"), size_guidance={"scalars": 0, "tensors": 0})
    reused.Reload()
    assert [(e.step, e.value) for e in reused.Scalars("train/relay/loss")] == [(0, 1.0)]
    assert not any(tag.startswith("train/decouple/") for tag in reused.Tags()["scalars"])
    (note,) = reused.Tensors("reused/decouple/text_summary")
    text = note.tensor_proto.string_val[0].decode()
    assert "**decouple**" in text and "(node `first`)" in text and "artifact store" in text
    assert f"artifact `{stored.name[:16]}`" in text
    assert "by run `a`" in text and "step, 5: loss 0.5" in text
    assert "reused/relay/text_summary" not in reused.Tags()["tensors"]


def _status_lines(out):
    """The lines that say what a job built, reused or evaluated (not the summary's)."""
    status = re.compile(r"(\[\w+\] )?\[\w+\] (built|evaluated|reused) ")
    return [line for line in out.splitlines() if status.match(line)]


def test_a_labelled_job_names_itself_on_every_line_and_writes_each_whole(
    base_config, tmp_path, monkeypatch
):
    # jobs of a parallel launcher print side by side on one unbuffered pipe: each line says
    # whose it is, and a line and its newline written apart would let another's land between
    fakes = FakeStages(notes={"decouple": ["no foreground"]})
    printed = []
    for label in ("3_k64", None):
        stdout, stderr = WriteRecorder(), WriteRecorder()
        monkeypatch.setattr("sys.stdout", stdout)
        monkeypatch.setattr("sys.stderr", stderr)
        _run(base_config, tmp_path / (label or "alone"), fakes, label=label)
        printed.append((stdout, stderr))
    (stdout, stderr), (alone, _) = printed
    writes = [text for text in stdout.writes + stderr.writes if text]
    assert sum("[decouple] " in text for text in writes) == 2  # its status line and its note
    assert all(text.startswith("[3_k64] ") and text.endswith("\n") for text in writes)
    out = stdout.getvalue()
    labelled = _status_lines(out)
    assert len(labelled) == 4  # three stages and the evaluation
    assert all(line.startswith("[3_k64] [") for line in labelled)
    # and so does every line of its results table and outputs block
    assert all(line.startswith("[3_k64] ") for line in out.splitlines())
    assert "\n[3_k64]   PSNR " in out and "\n[3_k64] outputs:\n[3_k64]   result " in out
    out = alone.getvalue()
    alone = _status_lines(out)
    assert len(alone) == 4 and all(line.startswith("[") for line in alone)
    assert "3_k64" not in out
    assert "\n  PSNR " in out and "\noutputs:\n  result " in out  # as a single run prints


def test_a_job_rerun_in_its_folder_counts_what_it_built_there_and_is_not_noted(
    base_config, tmp_path, capsys
):
    # a sweep resumed in place (as an interrupted one is told to): the rerun reuses everything,
    # yet the job built it all in its folder before the interruption, and finds its own result
    # there (no advice to give it another folder); a job in another folder built none of it
    fakes = FakeStages()
    folder = tmp_path / "sweep" / "0_k8"
    k8, overrides = with_values(base_config, relay__k=8), ["relay.k=8", "+component=full"]
    first = _run(k8, folder, fakes, overrides=overrides, job=0)
    assert first["train_s_built_by_job"] == first["train_s_computed"] > 0
    assert first["eval_s_built_by_job"] == first["eval_s_computed"] > 0
    (folder / RESULT_FILE).unlink()  # killed after its stages, before its result: its curves
    capsys.readouterr()
    again = _run(k8, folder, fakes, overrides=overrides, job=0)
    err = capsys.readouterr().err
    assert "already holds a run" not in err
    assert f"note: {folder} holds the TensorBoard curves of a run stopped before its " in err
    assert (again["train_s_computed"], again["eval_s_computed"], again["cache_hits"]) == (0, 0, 3)
    assert again["train_s_built_by_job"] == pytest.approx(first["train_s_computed"])
    assert again["eval_s_built_by_job"] == pytest.approx(first["eval_s_computed"])
    # resumed with settings that build nothing differently: still the same job
    quiet = with_values(k8, train__progress=False, train__checkpoint_every=7)
    built = _run(quiet, folder, fakes, overrides=overrides, job=0)["train_s_built_by_job"]
    assert built == pytest.approx(first["train_s_computed"])
    assert "already holds a run" not in capsys.readouterr().err
    other = _run(k8, tmp_path / "sweep" / "1_k8", fakes, job=1)
    assert (other["train_s_built_by_job"], other["eval_s_built_by_job"]) == (0, 0)
    assert fakes.ran("deform") == 1 and fakes.evaluations == 1
    # another sweep's job 0 in the same folder built only what its own setting changed
    k2 = with_values(base_config, relay__k=2)
    result = _run(k2, folder, fakes, overrides=["relay.k=2"], job=0)
    built_now = (result["train_s_computed"], result["eval_s_computed"])
    assert built_now == (result["train_s_built_by_job"], result["eval_s_built_by_job"])
    assert result["cache_hits"] == 1 and fakes.ran("deform") == 2
    note = f"note: {folder} already holds a run: its result.json is replaced"
    assert note in capsys.readouterr().err
    _run(k2, folder, fakes, overrides=["relay.k=2"], job=1)  # another job of a sweep
    assert note in capsys.readouterr().err
    _run(k2, folder, fakes)  # a pinned hydra.run.dir used again by a single run
    assert note in capsys.readouterr().err


def test_an_evaluation_without_per_view_metrics_leaves_no_file(base_config, tmp_path, capsys):
    _run(base_config, tmp_path / "a", FakeStages())
    assert (tmp_path / "a" / PER_VIEW_FILE).is_file()
    capsys.readouterr()
    fakes = FakeStages()
    whole = fakes._evaluate
    fakes._evaluate = lambda *args: {k: v for k, v in whole(*args).items() if k != PER_VIEW}
    _run(with_values(base_config, seed=1), tmp_path / "a", fakes)  # a new model, the same folder
    assert fakes.evaluations == 1
    assert not (tmp_path / "a" / PER_VIEW_FILE).exists()  # the earlier run's is gone
    assert "per view" not in capsys.readouterr().out


def test_the_runs_thread_count_keys_its_evaluation_and_its_printed_commands(
    base_config, tmp_path, capsys
):
    """Render FPS depends on the thread count, so a stored evaluation is reused only at the
    thread count it was measured with; the trained artifacts are reused whatever it is. The
    printed commands use as many threads: with torch's default instead, a render on a loaded
    2-core machine ran 25 times slower. The run's splat backend is the job's default too."""
    fakes = FakeStages()
    threads = torch.get_num_threads()
    try:
        _run(with_values(base_config, threads=1, splat__backend="torch"), tmp_path / "a", fakes)
        assert default_backend() == "torch"
        result = _run(with_values(base_config, threads=2), tmp_path / "b", fakes)
        two = capsys.readouterr().out
        _run(with_values(base_config, threads=2), tmp_path / "c", fakes)
        assert fakes.evaluations == 2 and fakes.ran("deform") == 1
        capsys.readouterr()
        _run(with_values(base_config, threads=None), tmp_path / "default", fakes)
        default = capsys.readouterr().out
        assert default_backend() == "auto"
    finally:
        torch.set_num_threads(threads)
        use_backend("auto")
    key = result["output_key"][:16]
    assert f" ply {key} --threads 2\n" in two and " --truth --error --threads 2\n" in two
    assert f" ply {key}\n" in default and " --truth --error\n" in default
    assert "--threads" not in default


def test_evaluation_key_names_the_thread_count_only_on_the_cpu():
    settings = {"eval": {"frame_stride": 1}}
    cpu = evaluation_config({**settings, "train": {"device": "cpu"}})
    cuda = evaluation_config({**settings, "train": {"device": "cuda"}})
    assert cpu["cpu_threads"] == torch.get_num_threads()
    assert "cpu_threads" not in cuda and cuda["device"] == "cuda"


def test_stages_receive_only_seed_train_and_their_section_overridden_and_scaled(
    base_config, tmp_path
):
    fakes = FakeStages()
    config = with_values(
        base_config, pipeline=pipeline_section("4dgs"), deform__steps=7, budget__multiplier=2.0
    )
    result = _run(config, tmp_path / "run", fakes, overrides=["pipeline=4dgs", "deform.steps=7"])
    deform_cfg = dict(fakes.calls)["deform"]
    assert deform_cfg["deform"]["gamma"] is False
    assert deform_cfg["deform"]["isolate_fg_bg"] is False
    assert deform_cfg["train"] == base_config["train"]
    assert result["pipeline"] == "4dgs"
    assert result["deform.gamma"] is False  # as the pipeline ran it, not the config default
    assert result["relay.k"] is None  # 4dgs runs no relay stage
    # the budget multiplier scales the steps every stage receives, the overridden ones too
    steps = {stage: cfg[stage]["steps"] for stage, cfg in fakes.calls}
    unscaled = {stage: base_config[stage]["steps"] for stage in steps} | {"deform": 7}
    assert steps == {stage: 2 * value for stage, value in unscaled.items()}


def test_training_scalars_are_grouped_so_rates_sort_after_the_fit():
    assert training_tag("relay", "loss") == "train/relay/loss"
    assert training_tag("relay", "psnr") == "train/relay/psnr"
    assert training_tag("relay", "num_fg") == "train_gaussians/relay/num_fg"
    assert training_tag("relay", "lr/means") == "train_lr/relay/means"


def test_the_suites_upstream_types_are_checked_before_any_stage_runs(base_config, tmp_path):
    pipeline = tmp_path / "wrong.yaml"
    pipeline.write_text("nodes:\n  a: {stage: warmup}\n  b: {stage: relay, upstream: [a]}\n")
    fakes = FakeStages()
    suite = dataclasses.replace(
        fakes.suite(), accepted_upstream=load_stage_suite().accepted_upstream
    )
    config = with_values(base_config, pipeline__name=str(pipeline))
    with refused(InputError, "'b'", "'relay'"):
        run_task(config, run_dir=tmp_path / "run", original_cwd=tmp_path, suite=suite)
    assert fakes.calls == []


@pytest.mark.parametrize(
    ("key", "value", "printed"),
    [
        ("scene__loader__downscale", 2, " --downscale 2 --truth --error --threads 1"),
        ("train__device", "cuda:1", " --truth --error --device cuda:1 --threads 1"),
        ("scene__loader__test_cameras", [4, 1], " --test-cameras 1,4 --truth --error --threads 1"),
        ("scene__loader__test_cameras", [], " --test-cameras '[]' --truth --error --threads 1"),
    ],
)
def test_the_printed_render_command_keeps_the_runs_settings(
    base_config, tmp_path, capsys, key, value, printed
):
    # the scene's downscale, the training device and the held-out cameras (smoke: threads=1)
    _run(with_values(base_config, **{key: value}), tmp_path / "run", FakeStages())
    videos = next(line for line in capsys.readouterr().out.splitlines() if "videos" in line)
    assert videos.endswith(printed)


@pytest.mark.parametrize(
    ("changed", "named"),
    [
        ({"relay__k": 0}, "relay.k"),
        ({"decouple__steps": -1}, "decouple.steps"),
        ({"pipeline__name": "nope"}, "'nope'"),
        ({"scene__path": "missing"}, "scene.path"),
        ({"seed": -3}, "seed"),
        ({"artifacts__on_corrupt": "ignore"}, "artifacts.on_corrupt"),
    ],
)
def test_bad_values_fail_before_any_stage_runs(base_config, tmp_path, changed, named):
    fakes = FakeStages()
    if "scene__path" in changed:
        changed = {"scene__path": str(tmp_path / changed["scene__path"])}
    with refused(InputError, named):
        _run(with_values(base_config, **changed), tmp_path / "run", fakes)
    assert fakes.calls == []
    assert not (tmp_path / "run").exists()


def test_bad_scene_data_fails_before_the_run_folder_is_touched(base_config, tmp_path):
    # a capture that is damaged: an earlier good result in the folder must survive
    fakes = FakeStages()
    _run(base_config, tmp_path / "run", fakes)
    good = (tmp_path / "run" / RESULT_FILE).read_text()
    capture = tmp_path / "capture"
    (capture / "cam00").mkdir(parents=True)
    with refused(InputError, str(capture)):
        _run(with_values(base_config, scene__path=str(capture)), tmp_path / "run", fakes)
    assert (tmp_path / "run" / RESULT_FILE).read_text() == good
    assert fakes.ran("decouple") == 1


def test_a_corrupted_artifact_or_evaluation_is_rebuilt_or_refused(base_config, tmp_path, capsys):
    fakes = FakeStages()
    _run(base_config, tmp_path / "a", fakes)
    (tensors,) = (tmp_path / "artifacts" / "decouple").glob("*/tensors.safetensors")
    data = bytearray(tensors.read_bytes())
    data[-1] ^= 0xFF
    tensors.write_bytes(bytes(data))
    (manifest,) = (tmp_path / "artifacts" / "eval").glob("*/manifest.json")
    manifest.write_text(manifest.read_text().replace('"', " ", 1) + " ")  # one byte changed
    refusing = with_values(base_config, artifacts__on_corrupt="error")
    with refused(CorruptArtifactError, "on_corrupt=error", str(tensors)):
        _run(refusing, tmp_path / "b", fakes)
    assert fakes.ran("decouple") == 1
    capsys.readouterr()
    result = _run(base_config, tmp_path / "c", fakes)
    assert fakes.ran("decouple") == 2 and result["cache_hits"] == 2
    out = capsys.readouterr().out.splitlines()
    (line,) = [line for line in out if "failed" in line and line.startswith("[decouple]")]
    assert line.startswith("[decouple] built decouple artifact ")
    reason = f"{tensors}: sha256 mismatch (recorded "
    assert "replacing the stored one" in line and reason in line
    (line,) = [line for line in out if line.startswith("[eval]")]
    assert line.startswith("[eval] evaluated the test views in ")
    assert "replacing the stored one" in line and "manifest" in line


def test_a_gc_removing_the_model_while_it_is_evaluated_does_not_fail_the_run(
    base_config, tmp_path, monkeypatch
):
    """`gc --keep` run beside a job removes the model it just built (its lock is free while
    the job evaluates): the job still reports the model's storage, from its manifest."""
    fakes = FakeStages()
    store = ArtifactStore(tmp_path / "artifacts")
    recorded = []
    real_evaluate = fakes._evaluate

    def evaluate_while_gc_runs(scene, artifact, cfg):
        stored = {item.stage: item for item in store.list()}
        model = stored["deform"]
        recorded.append(model.manifest.size_mb)
        store.gc(keep={stored["decouple"].key})
        assert not store.has("deform", model.key)
        return real_evaluate(scene, artifact, cfg)

    monkeypatch.setattr(fakes, "_evaluate", evaluate_while_gc_runs)
    result = _run(base_config, tmp_path / "a", fakes)
    assert result["status"] == "ok" and result["storage_mb"] == recorded[0] > 0


def test_hparams_metrics_of_zero_are_logged_and_missing_ones_skipped(tmp_path):
    # a job that reused every stage computed for 0 s; a metric it could not measure is None
    log = TensorBoardLog(tmp_path / "tb")
    metrics = {"psnr": 25.0, "train_s_computed": 0.0, "lpips": None}
    log.add_hparams({"relay.k": 8}, metrics, SweepAxes(), "job")
    log.close()
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    logged = {tag for tag in events.Tags()["scalars"] if tag.startswith("result/")}
    assert logged == {"result/psnr", "result/train_s_computed"}
    assert [event.value for event in events.Scalars("result/train_s_computed")] == [0.0]


def test_hparams_flatten_to_dotted_keys_with_none_as_text():
    config = {"a": {"b": None, "c": [1, 2], "d": {"e": 0.5}}, "f": True, "g": "x"}
    assert flatten_config(config) == {
        "a.b": "None",
        "a.c": "[1, 2]",
        "a.d.e": 0.5,
        "f": True,
        "g": "x",
    }


def test_non_finite_metrics_are_written_as_null(base_config, tmp_path, monkeypatch):
    # JSON has no NaN: a metric that came out NaN or infinite must read back as null rather
    # than break result.json. (The eval store refuses such metrics, so the evaluation is
    # replaced after it was stored.)
    real = task_module.evaluate_through_store

    def non_finite(*args, **kwargs):
        evaluation = real(*args, **kwargs)
        metrics = {**evaluation.metrics, "psnr": float("nan"), "lpips": float("inf")}
        return dataclasses.replace(evaluation, metrics=metrics)

    monkeypatch.setattr(task_module, "evaluate_through_store", non_finite)
    result = _run(base_config, tmp_path / "run", FakeStages())
    text = (tmp_path / "run" / RESULT_FILE).read_text()
    assert '"psnr": null' in text and "NaN" not in text and "Infinity" not in text
    written = json.loads(text)
    assert written == result
    assert written["psnr"] is None and written["ssim"] == 0.5
    assert "lpips" not in written  # extra metrics are kept only when they have a value


class KilledError(BaseException):
    """Stands in for a kill (or SIGTERM's KeyboardInterrupt) at the injected point."""


def test_a_result_write_stopped_part_way_keeps_the_previous_result(
    base_config, tmp_path, monkeypatch
):
    # a truncated result.json makes the sweep report refuse the whole sweep folder: a write
    # stopped before it completes must leave the previous result whole (and no stray file)
    run_dir = tmp_path / "run"
    before = _run(base_config, run_dir, FakeStages())

    def killed(source, target):
        raise KilledError

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KilledError):
        write_result(run_dir, {**before, "psnr": 1.0})
    monkeypatch.undo()
    assert json.loads((run_dir / RESULT_FILE).read_text()) == before
    files = sorted(p.name for p in run_dir.iterdir() if p.is_file() and ".tfevents." not in p.name)
    assert files == [PER_VIEW_FILE, RESULT_FILE]


def test_the_summary_says_why_a_run_without_test_views_has_no_metrics():
    shown = format_summary({"pipeline": "relaygs", "psnr": None, "num_test_images": 0})
    assert "PSNR" in shown and shown.splitlines()[-1] == f"  {NO_TEST_VIEWS}"
    assert NO_TEST_VIEWS not in format_summary({"psnr": 20.0, "num_test_images": 4})


@pytest.mark.parametrize(
    ("variant", "title"),
    [
        ("relaygs", "relaygs on juggle (seed 0)"),
        ("no_gamma", "no_gamma (relaygs) on juggle (seed 0)"),
        (None, "relaygs on juggle (seed 0)"),
    ],
)
def test_the_summary_title_names_the_variant_beside_its_pipeline(variant, title):
    result = {"variant": variant, "pipeline": "relaygs", "scene": "juggle", "seed": 0}
    assert format_summary(result).splitlines()[0] == title


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device", "/runs/x/.result.json.partial")


def _no_memory_in_relay(stage, cfg):
    if stage == "relay":
        raise MemoryError
    return False


@pytest.mark.parametrize(
    ("fail_when", "named", "cause"),
    [
        # the disk had room for per_view.csv, then refused result.json (and the failed one too)
        (None, ["No space left on device", "/runs/x/"], OSError),
        # a failed result the full disk refuses does not hide why the run failed
        (_no_memory_in_relay, ["relay", "out of memory"], MemoryError),
    ],
)
def test_a_full_disk_refusing_the_result_is_one_error_and_leaves_neither_file(
    base_config, tmp_path, monkeypatch, fail_when, named, cause
):
    monkeypatch.setattr(task_module, "write_result", _disk_full)
    run_dir = tmp_path / "run"
    with refused(errors.ResourceError, *named) as raised:
        _run(base_config, run_dir, FakeStages(fail_when=fail_when))
    assert isinstance(raised.value.__cause__, cause)
    assert not (run_dir / PER_VIEW_FILE).exists() and not (run_dir / RESULT_FILE).exists()
