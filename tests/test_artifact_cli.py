"""`python -m relaygs.artifacts`: ls, show, verify and gc, their output and exit codes."""

import errno
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from relaygs.cli import start_tool
from relaygs.commands import artifacts as artifacts_module
from relaygs.commands.artifacts import main
from relaygs.per_view import PER_VIEW, read_per_view
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.integrity import seal
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.manifest import LineageEntry
from relaygs.pipeline.store import ArtifactStore
from store_helpers import damage_dtype_and_rehash, flip_last_byte

KEY_A = artifact_key("decouple", 1, {"steps": 1}, "scene", [])
KEY_B = artifact_key("relay", 1, {"k": 2}, "scene", [KEY_A])


def _put(store, artifact, key, upstream=(), **provenance):
    """`artifact` stored under `key`, its lineage the (stage, key) pairs of `upstream`."""
    lineage = [LineageEntry(stage, stage, parent) for stage, parent in upstream]
    store.get_or_build(
        artifact.stage, key, lambda: artifact, config={}, lineage=lineage, provenance=provenance
    )


@pytest.fixture
def store(tmp_path):
    store = ArtifactStore(tmp_path / "store")
    _put(store, Artifact("decouple", {"xyz": torch.zeros(5, 3)}), KEY_A)
    _put(store, Artifact("relay", {"segment": torch.arange(5)}), KEY_B, [("decouple", KEY_A)])
    return store


def _cli(capsys, store_root, *args):
    code = main(["--root", str(store_root), *args])
    out, err = capsys.readouterr()
    return code, out, err


def _refused(capsys, store_root, *args, named=()):
    """Run a command that must fail: exit 1, nothing on stdout, one error line naming each of
    `named`; returns that line."""
    code, out, err = _cli(capsys, store_root, *args)
    assert (code, out, err.count("\n")) == (1, "", 1), (code, out, err)
    assert all(name in err for name in named), (err, named)
    return err


def _usage_error(capsys, *argv):
    """Run with `argv`, expect the one-line usage error of exit 2; returns that line."""
    with pytest.raises(SystemExit) as caught:
        main(list(argv))
    out, err = capsys.readouterr()
    assert (caught.value.code, out, err.count("\n")) == (2, "", 1), err
    return err


def test_ls_lists_finished_artifacts_and_gc_removes_leftovers_and_unkept_ones(store, capsys):
    leftover = store.root / "relay" / f".tmp-{KEY_B}-x"
    leftover.mkdir()
    blob = store.root / "blobs" / KEY_A  # e.g. --root at another tool's content-addressed cache
    blob.parent.mkdir()
    blob.write_text("not ours")
    code, out, _ = _cli(capsys, store.root, "ls")
    assert code == 0 and f"decouple:{KEY_A[:8]}" in out and "2 artifact(s)" in out
    assert "damaged" not in out
    assert KEY_A[:16] in out and KEY_B[:16] in out and ".tmp" not in out
    code, out, _ = _cli(capsys, store.root, "gc", "--dry-run")
    assert code == 0 and "would remove" in out and leftover.exists()
    _refused(capsys, store.root, "gc", "--keep", "beef", named=["'beef'"])
    assert leftover.exists() and store.has("relay", KEY_B)
    code, out, _ = _cli(capsys, store.root, "gc", "--keep", KEY_A[:8])
    assert code == 0 and not leftover.exists()
    assert store.has("decouple", KEY_A) and not store.has("relay", KEY_B)
    assert str(blob) not in out and blob.read_text() == "not ours"
    locks = store.root / ".locks"
    assert not any(locks.iterdir()) and ".lock\n" not in out  # two lock files, one line
    assert f"removed 2 folder(s) and 2 free lock file(s) (in {locks}), 0 in use\n" in out


def test_an_artifact_folder_that_cannot_be_read_is_one_problem_not_the_end(
    store, capsys, monkeypatch
):
    # chmod 000 on one artifact folder (as root here, permissions are simulated)
    is_file = Path.is_file
    denied = store.path("relay", KEY_B)

    def unreadable(path: Path) -> bool:
        if path.parent == denied:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return is_file(path)

    monkeypatch.setattr(Path, "is_file", unreadable)
    code, out, _ = _cli(capsys, store.root, "ls")
    assert code == 0 and KEY_A[:16] in out and "1 artifact(s)" in out
    code, out, _ = _cli(capsys, store.root, "verify")
    assert code == 1 and str(denied) in out and "Permission denied" in out
    assert _cli(capsys, store.root, "show", KEY_A[:8])[0] == 0


def test_show_prints_manifest_and_tensors_by_key_prefix_or_what_is_wrong(store, capsys):
    code, out, _ = _cli(capsys, store.root, "show", KEY_B[:10])
    assert code == 0
    assert f'"key": "{KEY_B}"' in out and "tensor segment: I64 [5]" in out
    _refused(capsys, store.root, "show", "ffff0000", named=["'ffff0000'"])
    (store.path("relay", KEY_B) / "tensors.safetensors").write_bytes(b"")
    named = ["damaged", "tensors.safetensors", "artifacts verify"]
    _refused(capsys, store.root, "show", KEY_B[:8], named=named)


def test_verify_exits_1_on_a_corrupt_artifact(store, capsys):
    assert _cli(capsys, store.root, "verify")[0] == 0
    victim = store.path("decouple", KEY_A) / "tensors.safetensors"
    flip_last_byte(victim)
    code, out, _ = _cli(capsys, store.root, "verify")
    assert code == 1 and "CORRUPT" in out and "tensors.safetensors" in out and KEY_B not in out
    assert out.splitlines()[-1] == artifacts_module.REPAIR_HINT
    assert _cli(capsys, store.root, "show", KEY_A[:8])[0] == 0  # reads only the manifest
    ply = ("ply", KEY_A[:8], "--out", str(store.root / "p"))
    _refused(capsys, store.root, *ply, named=[str(victim), "sha256"])


def test_verify_names_an_artifact_that_does_not_decode_and_counts_every_folder(store, capsys):
    undecodable = store.path("decouple", KEY_A)
    damage_dtype_and_rehash(undecodable)
    unparsable = store.path("relay", KEY_B)
    (unparsable / "manifest.json").write_text("{not json")
    seal(unparsable)
    code, out, _ = _cli(capsys, store.root, "verify")
    assert code == 1
    assert f"CORRUPT {undecodable}: " in out and "unreadable artifact files" in out
    assert f"CORRUPT {unparsable}: " in out
    assert "2 problem(s) among 2 artifact(s)" in out


def test_an_ambiguous_prefix_names_the_artifacts_it_matches(tmp_path, capsys):
    keys = {}
    steps = 0
    while True:  # two keys sharing their first 4 hex digits (a few hundred tries)
        key = artifact_key("decouple", 1, {"steps": steps}, "scene", [])
        if key[:4] in keys:
            break
        keys[key[:4]] = key
        steps += 1
    store = ArtifactStore(tmp_path / "store")
    for each in (keys[key[:4]], key):
        _put(store, Artifact("decouple", {"xyz": torch.zeros(1, 3)}), each)
    named = [f"'{key[:4]}'", f"decouple/{key[:16]}", f"decouple/{keys[key[:4]][:16]}"]
    _refused(capsys, store.root, "show", key[:4], named=named)


def test_gc_refuses_a_root_that_is_no_store_and_deletes_nothing(tmp_path, capsys):
    # --root at, say, Docker's overlay2: folders named by a sha256, none with a seal
    layer = tmp_path / "overlay2" / KEY_A
    (layer / "diff").mkdir(parents=True)
    (layer / "diff" / "file").write_text("not ours")
    _refused(capsys, tmp_path, "gc", named=[str(tmp_path)])
    assert (layer / "diff" / "file").read_text() == "not ours"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["overlay2"]  # no .locks made


def test_ctrl_c_during_a_command_is_one_line_and_status_130(store, capsys, monkeypatch):
    # a render or eval stopped by Ctrl-C (say while loading the scene) ends like a run does
    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(artifacts_module, "_ls", interrupted)
    monkeypatch.setattr(sys, "argv", ["artifacts", "--root", str(store.root), "ls"])
    with pytest.raises(SystemExit) as stop:
        start_tool("relaygs.commands.artifacts")
    assert (stop.value.code, *capsys.readouterr()) == (130, "", "interrupted\n")


def test_missing_store_is_one_line_error(tmp_path, capsys):
    _refused(capsys, tmp_path / "nowhere", "ls", named=[str(tmp_path / "nowhere")])


def test_eval_scores_a_stored_model_like_the_evaluator(stage_scene_path, stage_decoupled, tmp_path):
    from relaygs.data import load_scene
    from relaygs.stages import evaluate

    store = ArtifactStore(tmp_path / "store")
    key = artifact_key("decouple", 1, {"steps": 2}, "juggle", [])
    _put(store, stage_decoupled, key)
    views_csv = tmp_path / "scores" / "views.csv"
    argv = ("eval", key[:8], "--scene", str(stage_scene_path), "--frame-stride", "3", "--per-view")
    done = subprocess.run(
        [sys.executable, "-m", "relaygs.artifacts", "--root", str(store.root), *argv, views_csv],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    expected = evaluate(
        load_scene(stage_scene_path), stage_decoupled, {"eval": {"frame_stride": 3}}
    )
    assert f"psnr            {expected['psnr']:.4f}" in done.stdout
    assert f"num_fg          {expected['num_fg']}" in done.stdout
    stored_mb = store.manifest("decouple", key).size_mb  # what result.json reports
    assert f"storage_mb      {stored_mb:.4f}" in done.stdout
    written = read_per_view(views_csv)
    # another process's float32 render may differ in its last bits: scores agree to 1e-4
    assert written == [pytest.approx(record, rel=1e-4) for record in expected[PER_VIEW]]
    views = len(expected[PER_VIEW])
    assert f"per-view metrics of {views} image(s) in {views_csv}" in done.stdout


def test_eval_refuses_a_per_view_path_it_cannot_write_and_names_a_missing_scene(
    store, tmp_path, capsys
):
    blocker = tmp_path / "file"
    blocker.write_text("")
    for target in (tmp_path, blocker / "views.csv"):
        argv = ("--root", str(store.root), "eval", KEY_A[:8], "--scene", ".")
        err = _usage_error(capsys, *argv, "--per-view", str(target))
        assert "--per-view" in err and str(target) in err
    missing = str(tmp_path / "none")
    _refused(capsys, store.root, "eval", KEY_A[:8], "--scene", missing, named=[missing])


def test_gc_keeps_the_evaluations_of_kept_models_only_and_eval_refuses_them(store, capsys):
    evaluation = Artifact("eval", meta={"metrics": {"psnr": 20.0}})
    of_relay, of_decouple = (artifact_key("eval", 1, {}, "s", [key]) for key in (KEY_B, KEY_A))
    _put(store, evaluation, of_relay, [("relay", KEY_B)])
    _put(store, evaluation, of_decouple, [("decouple", KEY_A)])
    named = [of_relay[:16], "show"]  # it holds no model
    _refused(capsys, store.root, "eval", of_relay[:8], "--scene", ".", named=named)
    code, _, _ = _cli(capsys, store.root, "gc", "--keep", KEY_B)
    assert code == 0 and store.has("eval", of_relay) and store.has("eval", of_decouple)
    code, _, _ = _cli(capsys, store.root, "gc", "--keep", KEY_A)
    assert code == 0 and not store.has("relay", KEY_B)
    assert store.has("eval", of_decouple) and not store.has("eval", of_relay)


def test_show_of_an_artifact_gc_removes_meanwhile_says_removed_not_damaged(
    store, capsys, monkeypatch
):
    real_open = artifacts_module.safe_open

    def opened_after_a_gc(*args, **kwargs):
        store.gc(keep={KEY_A})  # `gc --keep` beside `show`, between finding and reading
        return real_open(*args, **kwargs)

    monkeypatch.setattr(artifacts_module, "safe_open", opened_after_a_gc)
    err = _refused(capsys, store.root, "show", KEY_B[:10], named=[f"relay/{KEY_B[:16]}"])
    assert "removed" in err and "damaged" not in err


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda manifest: "{broken", "manifest.json"),
        (lambda manifest: '"text"', "expected a JSON object, got str"),
        (lambda manifest: {**manifest, "wall_seconds": "1.5"}, "field 'wall_seconds'"),
        (lambda manifest: {**manifest, "files": ["tensors.safetensors"]}, "field 'files'"),
        (lambda manifest: {**manifest, "files": {"a": {}}}, "files entry 'a' has no byte"),
        (
            lambda manifest: {**manifest, "lineage": [{"node": "d", "stage": "d", "key": 7}]},
            "lineage entry is not an object of strings",
        ),
    ],
)
def test_a_resealed_manifest_of_the_wrong_shape_is_damaged_not_missing_or_a_crash(
    store, capsys, edit, problem
):
    folder = store.path("relay", KEY_B)
    edited = edit(json.loads((folder / "manifest.json").read_text()))
    (folder / "manifest.json").write_text(edited if isinstance(edited, str) else json.dumps(edited))
    seal(folder)  # hashes match: only the content is wrong
    code, out, _ = _cli(capsys, store.root, "ls")
    assert code == 0 and "1 artifact(s)" in out and "1 damaged artifact folder(s)" in out
    assert "artifacts verify" in out
    code, out, _ = _cli(capsys, store.root, "verify")
    assert code == 1 and "CORRUPT" in out and problem in out
    for command in (["show", KEY_B[:8]], ["gc", "--keep", KEY_B[:8]]):
        named = [f"relay/{KEY_B[:16]}", "damaged", problem]
        err = _refused(capsys, store.root, *command, named=named)
        assert err.count("delete its folder") == 1 and "artifacts verify" not in err  # one hint
    assert store.has("decouple", KEY_A)  # gc refused before removing anything


def _store_model(tmp_path, artifact, name="model", **provenance):
    """`artifact` in a new store under `tmp_path`, recorded as trained with `provenance`."""
    store = ArtifactStore(tmp_path / "store")
    key = artifact_key(artifact.stage, 1, {"steps": 2, "name": name}, "juggle", [])
    _put(store, artifact, key, **provenance)
    return store, key


def test_eval_refuses_a_scene_of_other_length_or_train_cameras(
    stage_decoupled, stage_scene_path, tiny_synth_scene, tmp_path, capsys
):
    store, key = _store_model(tmp_path, stage_decoupled)
    scene = str(tiny_synth_scene)
    _refused(capsys, store.root, "eval", key[:8], "--scene", scene, named=[scene, "8 frames"])
    held_out = _model_held_out(stage_decoupled, range(3, 31))
    store, key = _store_model(tmp_path, held_out, "held out")
    scene = str(stage_scene_path)
    _refused(capsys, store.root, "eval", key[:8], "--scene", scene, named=[scene, "3 train"])


@pytest.fixture
def stored_lineage(stage_decoupled, stage_relayed, stage_deformed, tmp_path):
    """The stage fixtures' decouple → relay → deform chain in a store, with its lineage."""
    store = ArtifactStore(tmp_path / "store")
    keys, upstream = {}, []
    for artifact in (stage_decoupled, stage_relayed, stage_deformed):
        stage = artifact.stage
        keys[stage] = artifact_key(stage, 1, {}, "juggle", [key for _, key in upstream])
        _put(store, artifact, keys[stage], upstream)
        upstream = [(stage, keys[stage])]
    return store, keys


def test_eval_lineage_and_gap_score_every_stage_upstream_first_and_need_every_one(
    stored_lineage, stage_scene_path, stage_decoupled, stage_relayed, stage_deformed, capsys
):
    from relaygs.data import load_scene
    from relaygs.stages import evaluate
    from relaygs.train.error_split import error_split

    store, keys = stored_lineage
    scene = load_scene(stage_scene_path)
    artifacts = {"decouple": stage_decoupled, "relay": stage_relayed, "deform": stage_deformed}
    argv = (keys["deform"][:8], "--scene", str(stage_scene_path), "--frame-stride", "4")
    code, out, err = _cli(capsys, store.root, "eval", *argv, "--lineage")
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == (
        f"deform {keys['deform'][:16]} and its lineage on {stage_scene_path} "
        "(test cameras 0, 10, 15, 30)"
    )
    columns = ["psnr", "ssim", "fg_psnr", "num_gaussians", "storage_mb"]
    assert lines[1].split() == ["stage", "key", *columns] and len(lines) == 5
    for line, stage in zip(lines[2:], artifacts, strict=True):
        metrics = evaluate(scene, artifacts[stage], {"eval": {"frame_stride": 4}})
        scores = [f"{metrics['psnr']:.4f}", f"{metrics['ssim']:.4f}"]
        assert line.split()[:4] == [stage, keys[stage][:16], *scores]
    code, out, err = _cli(capsys, store.root, "gap", *argv)
    assert code == 0, err
    lines = out.splitlines()
    names = ("psnr", "fg_psnr", "bg_psnr")
    splits = [f"{split}_{name}" for split in ("train", "test") for name in names]
    assert lines[1].split() == ["stage", "key", *splits, "gap"] and len(lines) == 5
    for line, stage in zip(lines[2:], artifacts, strict=True):
        train = error_split(scene, artifacts[stage], "train", frame_stride=4)
        test = error_split(scene, artifacts[stage], "test", frame_stride=4)
        cells = line.split()
        assert cells[:3] == [stage, keys[stage][:16], f"{train['psnr']:.4f}"]
        assert cells[5] == f"{test['psnr']:.4f}"
        assert float(cells[8]) == pytest.approx(train["psnr"] - test["psnr"], abs=1e-4)
    code, out, err = _cli(capsys, store.root, "gap", *argv, "--colour-fit")
    assert code == 0, err
    first = out.splitlines()[2].split()
    fitted = error_split(scene, stage_decoupled, "train", frame_stride=4, colour_fit=True)
    assert "colour-fitted" in out.splitlines()[0] and first[2] == f"{fitted['psnr']:.4f}"
    # a damaged or removed upstream artifact is named before any output
    flip_last_byte(store.path("relay", keys["relay"]) / "tensors.safetensors")
    _refused(capsys, store.root, "eval", *argv, "--lineage", named=[keys["relay"][:16], "damaged"])
    shutil.rmtree(store.path("decouple", keys["decouple"]))
    named = [keys["decouple"][:16], str(store.root)]
    _refused(capsys, store.root, "eval", *argv, "--lineage", named=named)


def _model_held_out(stage_decoupled, held_out):
    """The decouple model as deform would store it after training on every camera of the
    stage scene but `held_out` (its colour affine is fit to those train cameras)."""
    from relaygs.field import ColorAffine
    from relaygs.train.scene_model import SceneModel

    model = SceneModel.from_artifact(stage_decoupled)
    model.affine_cameras = [camera for camera in range(31) if camera not in held_out]
    model.affine = ColorAffine(len(model.affine_cameras))
    return model.to_artifact({})


def test_eval_and_render_take_the_runs_test_cameras(
    stage_decoupled, stage_scene_path, tmp_path, capsys
):
    from relaygs.data import load_scene
    from relaygs.stages import evaluate

    artifact = _model_held_out(stage_decoupled, [1, 5])
    store, key = _store_model(tmp_path, artifact)
    scene = ("--scene", str(stage_scene_path))
    _refused(capsys, store.root, "eval", key[:8], *scene, named=["[1, 5]", "--test-cameras 1,5"])
    code, out, err = _cli(capsys, store.root, "eval", key[:8], *scene, "--test-cameras", "1,5")
    assert code == 0, err
    assert f"on {stage_scene_path} (test cameras 1, 5)" in out.splitlines()[0]
    expected = evaluate(load_scene(stage_scene_path, test_cameras=[1, 5]), artifact, {})
    assert f"psnr            {expected['psnr']:.4f}" in out
    out_dir = tmp_path / "renders"
    render = ("render", key[:8], *scene, "--frame-stride", "8", "--no-video", "--out")
    code, out, err = _cli(capsys, store.root, *render, str(out_dir), "--test-cameras", "[1, 5]")
    assert code == 0, err
    assert sorted(path.name for path in out_dir.iterdir()) == ["cam01", "cam05"]


def test_the_note_comes_when_the_files_or_the_given_options_differ_from_the_run(
    stage_decoupled, stage_scene_path, tmp_path, capsys
):
    from relaygs.data import load_scene

    scene = ("--scene", str(stage_scene_path), "--frame-stride", "8")
    trained_on = load_scene(stage_scene_path, test_cameras=[1, 5]).fingerprint
    recorded = {"downscale": 1, "test_cameras": [1, 5]}
    notes = {}
    for name, fingerprint in (("same files", trained_on), ("other files", "0" * 64)):
        store, key = _store_model(tmp_path, stage_decoupled, name, scene=fingerprint, **recorded)
        for given in ((), ("--test-cameras", "1,6"), ("--test-cameras", "5,1,5")):
            code, _, err = _cli(capsys, store.root, "eval", key[:8], *scene, *given)
            assert code == 0 and err.count("\n") <= 1
            notes[name, given] = err
    assert notes["same files", ()] == ""  # loaded as its run loaded it
    assert notes["same files", ("--test-cameras", "5,1,5")] == ""  # the same cameras
    noted = [case for case, err in notes.items() if err.startswith("note: decouple")]
    assert len(noted) == 4 and ("same files", ("--test-cameras", "1,6")) in noted
    said = f"note: decouple {key[:16]} was not trained on {stage_scene_path} as"
    assert notes["other files", ()].startswith(said)
    render = ("render", key[:8], *scene, "--no-video", "--camera", "3")
    code, _, err = _cli(capsys, store.root, *render, "--out", str(tmp_path / "r"))
    assert code == 0 and err.rsplit("\r", 1)[-1].startswith(said)


def test_a_model_trained_on_every_camera_is_told_to_load_none_as_test_cameras(
    stage_decoupled, stage_scene_path, tmp_path, capsys
):
    store, key = _store_model(tmp_path, _model_held_out(stage_decoupled, []))
    argv = ("eval", key[:8], "--scene", str(stage_scene_path), "--frame-stride", "8")
    _refused(capsys, store.root, *argv, named=["every camera"])
    code, out, _ = _cli(capsys, store.root, *argv, "--test-cameras", "[ ]")
    assert code == 0 and "(test cameras none)" in out and "num_test_images 0" in out


def test_eval_and_render_load_the_test_cameras_the_run_chose(
    stage_decoupled, stage_scene_path, tmp_path, capsys
):
    from relaygs.data import load_scene

    chosen = load_scene(stage_scene_path, test_cameras=[1, 5]).fingerprint
    # as a run records it
    store, key = _store_model(tmp_path, stage_decoupled, scene=chosen, test_cameras=[1, 5])
    argv = ("eval", key[:8], "--scene", str(stage_scene_path), "--frame-stride", "8")
    code, out, err = _cli(capsys, store.root, *argv)
    assert code == 0 and err == "" and "(test cameras 1, 5)" in out.splitlines()[0]
    render = ("render", key[:8], "--scene", str(stage_scene_path), "--frame-stride", "8")
    code, _, err = _cli(capsys, store.root, *render, "--no-video", "--out", str(tmp_path / "r"))
    assert code == 0 and "note:" not in err
    assert sorted(path.name for path in (tmp_path / "r").iterdir()) == ["cam01", "cam05"]


def test_a_scene_error_the_recorded_loading_causes_and_only_that_is_blamed_on_it(
    stage_decoupled, stage_scene_path, tmp_path, capsys
):
    store, key = _store_model(tmp_path, stage_decoupled, scene="another", test_cameras=[99])
    argv = ("eval", key[:8], "--scene", str(stage_scene_path))
    _refused(capsys, store.root, *argv, named=["[99]", key[:16], "--test-cameras"])
    # max_points is recorded, but no flag can replace it
    store, key = _store_model(tmp_path, stage_decoupled, "other", scene="another", max_points=0)
    missing = str(tmp_path / "no-such-scene")
    err = _refused(capsys, store.root, "eval", key[:8], "--scene", missing, named=[missing])
    assert "manifest" not in err
    argv = ("eval", key[:8], "--scene", str(stage_scene_path))
    _refused(capsys, store.root, *argv, named=["max_points", key[:16], "manifest"])


def test_eval_renders_on_the_device_given_and_refuses_an_unusable_one(
    stored_deform, stage_scene_path, capsys, monkeypatch
):
    from relaygs.commands import artifacts_eval

    store, key = stored_deform
    argv = ("eval", key[:8], "--scene", str(stage_scene_path), "--frame-stride", "8")
    unusable = f"cuda:{torch.cuda.device_count()}" if torch.cuda.is_available() else "cuda"
    _refused(capsys, store.root, *argv, "--device", unusable, named=["--device", repr(unusable)])
    given = []
    real = artifacts_eval.evaluate
    monkeypatch.setattr(
        artifacts_eval, "evaluate", lambda *args: given.append(args[2]) or real(*args)
    )
    # stored without provenance, as by older versions: no note whatever the scene's fingerprint
    code, _, err = _cli(capsys, store.root, *argv, "--device", "cpu", "--downscale", "2")
    assert code == 0 and err == ""
    assert given == [{"eval": {"frame_stride": 8}, "train": {"device": "cpu"}}]


@pytest.mark.parametrize(
    ("error", "message"),
    [
        (OSError(errno.ENOSPC, "No space left on device", "/out/f.png"), "No space left"),
        (RuntimeError("DefaultCPUAllocator: can't allocate memory: 8 bytes"), "out of memory"),
    ],
    ids=["disk-full", "out-of-memory"],
)
def test_a_render_out_of_disk_or_memory_is_one_line(store, capsys, monkeypatch, error, message):
    def failing(*args, **kwargs):
        raise error

    monkeypatch.setattr(artifacts_module, "model_artifact", failing)
    code, _, err = _cli(capsys, store.root, "render", KEY_A[:8], "--scene", "s", "--out", "o")
    assert code == 1 and err.startswith(f"error: {message}") and err.count("\n") == 1
    assert err.rstrip().endswith("then rerun the command")


@pytest.fixture
def torch_threads():
    """torch's CPU thread count, restored after the test (a command under test sets it)."""
    before = torch.get_num_threads()
    yield before
    torch.set_num_threads(before)


@pytest.mark.parametrize("command", ["eval", "gap", "render", "ply"])
def test_threads_is_set_before_the_model_loads(store, capsys, monkeypatch, torch_threads, command):
    from relaygs.commands import artifacts_eval
    from relaygs.errors import RelayGSError

    seen = []

    def loading(*args):  # the first of the work: record torch's threads, then stop
        seen.append(torch.get_num_threads())
        raise RelayGSError("stopped")

    for module in (artifacts_module, artifacts_eval):
        monkeypatch.setattr(module, "model_artifact", loading)
    wanted = 1 if torch_threads > 1 else 2
    scene = [] if command == "ply" else ["--scene", "s"]
    code, _, err = _cli(capsys, store.root, command, KEY_A[:8], *scene, "--threads", str(wanted))
    assert (code, err, seen) == (1, "error: stopped\n", [wanted])


BAD_FLAG_VALUES = [
    *(("--test-cameras", given) for given in ["1,x", "-1", "1;5", "1,,5", "²", "\u0661", "", " "]),
    *(("--downscale", given) for given in ["0", "-2", "x"]),
    *(("--threads", given) for given in ["0", "-2", "x", "1.5", "1025"]),
    ("--frame-stride", "0"),
]
EVAL_A = ["eval", KEY_A[:8], "--scene", "."]


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["frobnicate"], "frobnicate"),
        (["show"], "key"),
        (["gc", "--keep"], "--keep"),
        (["eval", KEY_A[:8]], "--scene"),
        ([*EVAL_A, "--lineage", "--per-view", "v.csv"], "--lineage"),
        # a malformed key prefix
        (["show", "zzzz"], "hex digits"),
        (["show", "abc"], "hex digits"),
        (["ply", "xyz1"], "hex digits"),
        (["render", "abcd", "--scene", "s", "--beside", "zz"], "hex digits"),
        (["gc", "--keep", "abcd", "nothex"], "hex digits"),
        *(([*EVAL_A, flag, given], flag) for flag, given in BAD_FLAG_VALUES),
    ],
)
def test_a_usage_error_is_one_line_naming_the_argument(capsys, argv, named):
    assert named in _usage_error(capsys, *argv)


def test_help_still_works(capsys):
    with pytest.raises(SystemExit) as caught:
        main(["show", "--help"])
    assert caught.value.code == 0 and "usage:" in capsys.readouterr().out
