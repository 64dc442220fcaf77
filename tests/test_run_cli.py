"""`python -m relaygs.run`: one-line errors before any work, and the Hydra wiring (run dirs,
multirun, the sweep-summary callback) driven in-process on fake stages."""

import ast
import dataclasses
import errno
import io
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import torch
import yaml
from hydra.errors import HydraException

from conftest import run_main
from fake_stages import TINY_SCENE
from refusals import refused
from relaygs.app import prelaunch
from relaygs.commands import run as run_module
from relaygs.commands.artifacts import _parser as artifacts_parser
from relaygs.data.synthetic import PRESETS
from relaygs.errors import RERUN_RUN, InputError, Interrupted
from relaygs.paths import config_dir
from relaygs.shell import script_command

UNUSABLE_GPU = f"cuda:{torch.cuda.device_count()}"
"""One past the last GPU: unusable on every machine, a CPU-only torch included."""


@pytest.mark.parametrize(
    ("args", "named"),
    [
        # Hydra's and OmegaConf's own refusals, passed on in one line
        (["+experiment=nope"], ["experiment/nope"]),
        (["pipeline=nope"], ["pipeline/nope"]),
        (["scene=mars"], ["scene/mars"]),
        (["train=nope"], ["train/nope"]),
        (["hydra/launcher=nope"], ["hydra/launcher/nope"]),
        (["experiment=smoke"], ["+experiment=smoke"]),
        (["+pipeline=4dgs"], ["pipeline"]),
        (["relay.k=8,16"], ["relay.k=8,16", "--multirun"]),
        (["relay.kk=3"], ["relay.kk"]),
        (["-m", "relay.kk=1,2"], ["relay.kk"]),
        (["relay.k=x"], ["relay.k=x"]),
        (["relay.k=[1,"], ["[1,"]),
        (["paths.outputs=/tmp/scène"], ["paths.outputs"]),
        (["deform.multires={a:1}"], ["deform.multires"]),
        (["decouple.densify=[1]"], ["decouple.densify"]),
        (["scene.loader={zoom:2}"], ["scene.loader"]),
        (["+relay={kk:2}"], ["kk"]),
        (["--cfg", "job", "scene=mars"], ["scene/mars"]),
        (["--cfg", "job", "nosuch=1"], ["nosuch"]),
        (["--info", "defaults", "relay.k=[1,"], ["[1,"]),
        (["-m", "relay.k=8,16", "--cfg", "job"], ["--cfg", "--multirun"]),
        (["-r", "-c", "job"], ["--cfg", "--run"]),
        (["relay.k=0", "-r"], ["relay.k"]),  # checked before any work, as without -r
        # value ranges, and what only the run knows, planned for every job before any starts
        (["relay.k=0"], ["relay.k"]),
        (["decouple.steps=-5"], ["decouple.steps"]),
        (["-m", "variant=../../x", "relay.k=8,16"], ["variant", "../../x"]),
        (["scene.path=/no/such/capture"], ["scene.path", "/no/such/capture"]),
        # a capture has its own frames and size: a preset's setting beside it would be ignored
        (["scene.path=/data/cap", "scene.frames=4"], ["scene.frames=4", "scene.path"]),
        (["scene=court", "scene.path=/data/cap"], ["scene=court", "scene.path"]),
        (["scene.path=", "scene.frames=4"], ["scene.path"]),
        (["-m", "scene.path=/data/cap", "scene.width=8,16"], ["job scene.width=8", "scene.path"]),
        # a job is named by what tells it from the others: the swept overrides
        (["-m", "relay.k=16,0"], ["job relay.k=0: relay.k"]),
        (["-m", "budget=smoke", "relay.k=8,0", "seed=3"], ["job relay.k=0: relay.k"]),
        (["-m", "relay.k=8,0", "seed=1,2", "budget=smoke"], ["job relay.k=0 seed=1: relay.k"]),
        (["+experiment=ablation_k", "relay.k=0"], ["job relay.k=0 +experiment=ablation_k: "]),
        (["+experiment=budget", "budget.multiplier=0.5,-1"], ["budget.multiplier"]),
        (["relay.k=${nope}"], ["nope"]),
        (["scene.loader=abc"], ["scene.loader"]),
        (["scene.effects=[dynamic_panels]"], ["scene.effects", "juggle"]),
        (["tensorboard.preview_frames=abc"], ["tensorboard.preview_frames"]),
        (["+tensorboard.every=3"], ["tensorboard", "every"]),
        (["tensorboard.hparams=some"], ["tensorboard.hparams"]),
        (["hydra.run.dir=/proc/relaygs-run"], ["hydra.run.dir", "/proc"]),
        # Path("") is the folder the command started in: the run's files would land there
        (["hydra.run.dir="], ["hydra.run.dir"]),
        (["-m", "hydra.sweep.dir=' '"], ["hydra.sweep.dir"]),
        (["-m", "hydra.sweep.dir=/proc/relaygs-sweep"], ["hydra.sweep.dir", "/proc"]),
        (["artifacts.root=/proc/relaygs-store"], ["artifacts.root", "/proc"]),
        # torch takes no seed past int64: a traceback in the first stage before
        (["seed=100000000000000000000"], ["seed"]),
        (["scene.width=100000000000000000000"], ["scene.width"]),
        ([f"train.device={UNUSABLE_GPU}"], ["train.device", UNUSABLE_GPU]),
        (["train.device=tpu"], ["train.device", "tpu"]),
        # values that failed with a traceback, or were taken and broke the job only later
        (["paths.outputs=null"], ["paths.outputs"]),
        (["artifacts.root=[a]"], ["artifacts.root"]),
        (["~artifacts.root"], ["artifacts.root"]),
        (["scene.preset=[a]"], ["scene.preset"]),
        (["scene.effects=3"], ["scene.effects"]),
        (["scene.loader.test_cameras=3"], ["scene.loader.test_cameras"]),
        (["scene.loader.downscale=0"], ["scene.loader.downscale"]),
        (["scene.loader.test_cameras=[1,-2]"], ["scene.loader.test_cameras"]),
        (["scene.loader.test_cameras=[2,31,40]"], ["scene.loader.test_cameras", "[31, 40]"]),
        (
            [f"scene.loader.test_cameras=[{','.join(map(str, range(34)))}]", "scene=court"],
            ["scene.loader.test_cameras", "court"],
        ),
        (["budget.multiplier=1e307"], ["budget.multiplier"]),
        (["experiment_name=[a]"], ["experiment_name"]),
        (["report.reference=[1]"], ["report.reference"]),
        (["variant=null"], ["variant"]),
        # a typo added with `+` in a section that is not a stage's
        (["+budget.multipler=2"], ["budget", "multipler"]),
        (["+paths.output=x"], ["paths", "output"]),
        (["+sed=1"], ["sed"]),
        (["threads=100000"], ["threads"]),
        (["splat.backend=fast"], ["splat.backend"]),
    ],
)
def test_bad_input_is_one_line_before_any_work(fakes, tmp_path, capsys, args, named):
    assert run_main(args) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert [name for name in named if name not in lines[0]] == [], lines[0]
    assert fakes.calls == []
    assert list(tmp_path.iterdir()) == []  # no run dir, no store, no scene


def test_a_preset_edited_to_test_cameras_beyond_its_rig_is_one_line_before_any_work(
    fakes, tmp_path, capsys, monkeypatch
):
    # as `relaygs.synth` refuses it; before, `run` took it
    edited = dataclasses.replace(PRESETS["juggle"], test_cameras=(0, 99))
    monkeypatch.setitem(PRESETS, "juggle", edited)
    assert run_main([*TINY_SCENE]) == 1
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: ") and "PRESETS['juggle'].test_cameras" in line
    assert fakes.calls == [] and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("override", "fragment"),
    [
        ("artifacts.root=taken", "artifacts.root: {root}/taken is not a folder"),
        ("paths.outputs=taken/out", "paths.outputs: cannot create {root}/taken/out: {root}/taken"),
    ],
)
def test_an_output_path_through_a_file_fails_before_any_work(
    fakes, tmp_path, capsys, override, fragment
):
    (tmp_path / "taken").write_text("a file where a folder should be")
    assert run_main([override]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and fragment.format(root=tmp_path) in lines[0], lines
    assert fakes.calls == []
    assert [path.name for path in tmp_path.iterdir()] == ["taken"]


@pytest.mark.parametrize(
    ("launcher", "runs_here"), [("basic", True), ("joblib", True), ("slurm", False)]
)
def test_the_device_is_checked_here_unless_the_launcher_sends_jobs_elsewhere(
    tmp_path, monkeypatch, launcher, runs_here
):
    plugins = {"joblib": "hydra_joblib_launcher", "slurm": "hydra_submitit_launcher"}
    pytest.importorskip(f"hydra_plugins.{plugins.get(launcher, 'hydra_joblib_launcher')}")
    monkeypatch.setattr(prelaunch.shutil, "which", lambda name: f"/usr/bin/{name}")
    seen = []
    args = ["-m", f"hydra/launcher={launcher}", "relay.k=8,16", f"hydra.sweep.dir={tmp_path}"]
    prelaunch.check_command_line(
        args, config_dir(), lambda cfg, here: seen.append((cfg.relay.k, here))
    )
    assert seen == [(8, runs_here), (16, runs_here)]


def _experiment(tmp_path, text):
    """A copy of conf/ with experiment `plain` holding `text` after the package line."""
    conf = shutil.copytree(config_dir(), tmp_path / "conf")
    (conf / "experiment" / "plain.yaml").write_text(f"# @package _global_\n{text}")
    return conf


def test_an_unknown_choice_an_experiment_sweeps_is_found_before_any_job(tmp_path):
    sweep = "hydra:\n  mode: MULTIRUN\n  sweeper:\n    params:\n      pipeline: relaygs,nope\n"
    seen = []
    with pytest.raises(HydraException, match="pipeline/nope"):
        prelaunch.check_command_line(
            ["+experiment=plain"], _experiment(tmp_path, sweep), lambda cfg, h: seen.append(1)
        )
    assert seen == [1]  # the first job, relaygs, composed


def test_a_group_an_experiment_adds_is_changed_without_a_plus(tmp_path):
    conf = _experiment(tmp_path, "defaults:\n  - /component: no_gamma\n")
    seen = []
    args = ["+experiment=plain", "component=no_stage2"]
    prelaunch.check_command_line(args, conf, lambda cfg, here: seen.append(cfg.variant))
    assert seen == ["no_stage2"]
    with pytest.raises(HydraException, match="component"):
        prelaunch.check_command_line(["+experiment=plain", "+component=no_stage2"], conf, print)


@pytest.mark.parametrize(
    "path", ["~scene.path", "~scene.path=/data/cap", "scene.path=null", "scene.path=NULL"]
)
def test_a_deleted_or_null_scene_path_leaves_a_synthetic_scene_its_settings(tmp_path, path):
    # a scene file (or an experiment) may set a capture's path: without it the scene is
    # synthetic, and its frames are the command line's to set
    conf = shutil.copytree(config_dir(), tmp_path / "conf")
    (conf / "scene" / "capture.yaml").write_text(
        "defaults: [/base/synthetic_scene@_here_, _self_]\npreset: juggle\npath: /data/cap\n"
    )
    seen = []
    prelaunch.check_command_line(
        ["scene=capture", path, "scene.frames=8"],
        conf,
        lambda cfg, here: seen.append((cfg.scene.get("path"), cfg.scene.frames)),
    )
    assert seen == [(None, 8)]


def test_a_slurm_sweep_off_a_cluster_is_one_line_before_any_work(fakes, tmp_path, capsys):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    assert run_main(["-m", "hydra/launcher=slurm", "relay.k=8,16"]) == 1
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: hydra/launcher: ") and "sbatch" in line
    assert list(tmp_path.iterdir()) == []


def _terminate(stage, step, scalars, images=None):
    """A sink that stops the job as `kill PID` does, where no stage says where it stopped."""
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)  # the handler raises before this ends


def _interrupt(stage, step, scalars, images=None):
    """A sink that stops the job as Ctrl-C in a stage's training loop does."""
    raise Interrupted(f"{stage} stopped after step 3 of 9; run the same command again")


def _stop_in_relay(stage, step, scalars, images=None):
    """A sink that stops the job as SIGTERM would once decouple is built, in relay."""
    if stage == "relay":
        raise KeyboardInterrupt


@pytest.mark.parametrize(
    ("stop", "status", "stopped", "hits"),
    [
        (_interrupt, run_module.INTERRUPTED_EXIT, "decouple stopped after step 3 of 9; run the", 0),
        # a stage that cannot say where it stopped (a fake one here, a parallel launcher's
        # worker in a real sweep): the line says what running the command again does
        (_terminate, run_module.TERMINATED_EXIT, RERUN_RUN, 0),
        (_stop_in_relay, run_module.INTERRUPTED_EXIT, RERUN_RUN, 1),
    ],
)
def test_a_stopped_run_is_told_to_rerun_in_its_folder_and_is_credited_with_both_attempts(
    fakes, tmp_path, capsys, stop, status, stopped, hits
):
    # the same command again would go on in a new timestamped folder, crediting the decouple
    # the stopped attempt built to no job
    assert (run_module.INTERRUPTED_EXIT, run_module.TERMINATED_EXIT) == (130, 143)
    fakes.sinks.append(stop)
    previous = signal.getsignal(signal.SIGTERM)
    args = ["budget=smoke", *TINY_SCENE]
    assert run_main(args) == status
    assert signal.getsignal(signal.SIGTERM) is previous
    [folder] = (tmp_path / "outputs" / "runs").iterdir()
    last = capsys.readouterr().err.strip().splitlines()[-1]
    suffix = " to the command, so that the run goes on in its folder, not a new one"
    assert last.startswith(f"interrupted: {stopped}") and last.endswith(suffix)
    [override] = shlex.split(last.removesuffix(suffix).rpartition("; add ")[2])
    assert override == f"hydra.run.dir={folder}"
    fakes.sinks.remove(stop)
    assert run_main([*args, override]) == 0
    assert "already holds a run" not in capsys.readouterr().err
    result = json.loads((folder / "result.json").read_text())
    assert result["cache_hits"] == hits and fakes.ran("decouple") == 2 - hits
    assert result["train_s_built_by_job"] == result["train_s_total"]
    assert list((tmp_path / "outputs" / "runs").iterdir()) == [folder]


@pytest.mark.parametrize(
    ("stop", "status", "stopped"),
    [
        (_terminate, run_module.TERMINATED_EXIT, RERUN_RUN),
        (_interrupt, run_module.INTERRUPTED_EXIT, "decouple stopped after step 3 of 9; run the"),
    ],
)
def test_an_interrupted_sweep_is_told_to_rerun_in_its_own_folder(
    fakes, tmp_path, capsys, stop, status, stopped
):
    # the same command again would go on in a new timestamped folder, leaving this one
    # without a summary: the line names the folder, quoted to paste as one override (a comma
    # or space in it inside Hydra's quotes, or the rerun would sweep over it)
    fakes.sinks.append(stop)
    args = ["-m", "relay.k=8,16", "budget=smoke", 'paths.outputs="my out,2"', *TINY_SCENE]
    assert run_main(args) == status
    [folder] = (tmp_path / "my out,2" / "sweeps").iterdir()
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"interrupted: {stopped}")
    suffix = " to the command, so that the sweep goes on in its folder, not a new one"
    assert last.endswith(suffix)
    [override] = shlex.split(last.removesuffix(suffix).rpartition("; add ")[2])
    assert override == f'hydra.sweep.dir="{folder.relative_to(tmp_path)}"'
    fakes.sinks.remove(stop)
    assert run_main([*args, override]) == 0
    assert (folder / "summary.md").is_file()
    assert list((tmp_path / "my out,2" / "sweeps").iterdir()) == [folder]


def test_an_interrupted_sweep_in_a_folder_the_command_names_is_told_to_rerun_it(
    fakes, tmp_path, capsys
):
    fakes.sinks.append(_terminate)
    folder = tmp_path / "sweep"
    args = ["-m", "relay.k=8,16", "budget=smoke", f"hydra.sweep.dir={folder}", *TINY_SCENE]
    assert run_main(args) == run_module.TERMINATED_EXIT
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"interrupted: {RERUN_RUN}"


@pytest.mark.parametrize(
    ("signum", "status"),
    [(signal.SIGINT, run_module.INTERRUPTED_EXIT), (signal.SIGTERM, run_module.TERMINATED_EXIT)],
)
def test_a_signal_while_the_command_line_is_checked_is_one_line_not_a_traceback(
    fakes, monkeypatch, tmp_path, capsys, signum, status
):
    # composing and validating every job comes before Hydra starts and takes a while: a Ctrl-C
    # or SIGTERM then must end the command as one during a stage does
    def stopped(*args):
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the handler raises before this ends

    monkeypatch.setattr(run_module, "check_command_line", stopped)
    previous = signal.getsignal(signal.SIGTERM)
    # Python's own Ctrl-C handler, whatever this process inherited (a shell's background job
    # starts with SIGINT ignored)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert run_main(["budget=smoke", *TINY_SCENE]) == status
    finally:
        signal.signal(signal.SIGINT, inherited)
    assert capsys.readouterr().err.strip() == "interrupted"
    assert signal.getsignal(signal.SIGTERM) is previous
    assert list(tmp_path.iterdir()) == []


def test_help_completion_and_cfg_print_and_do_no_work(fakes, tmp_path, capsys):
    assert run_main(["--help"]) in (0, None)
    shown = capsys.readouterr().out
    assert shown.startswith("python -m relaygs.run: train and evaluate RelayGS")
    assert "relaygs.run +experiment=ablation_k" in shown
    experiments = sorted(path.stem for path in (config_dir() / "experiment").glob("*.yaml"))
    assert f"experiment: {', '.join(experiments)}" in shown
    commands = next(a for a in artifacts_parser()._actions if a.dest == "command").choices
    assert f"python -m relaygs.artifacts {' | '.join(commands)}\n" in shown  # every command
    # shell completion and --cfg are left to Hydra
    assert run_main(["-sc", "install=bash"]) == 0
    assert "complete" in capsys.readouterr().out  # the bash completion script
    assert run_main(["--cfg", "job", "relay.k=4"]) in (0, None)
    assert yaml.safe_load(capsys.readouterr().out)["relay"]["k"] == 4
    assert fakes.calls == [] and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "loader",
    [
        [],
        [
            "scene.loader.test_cameras=[2,0]",
            "scene.loader.downscale=2",
            "scene.loader.max_points=300",
        ],
    ],
)
def test_a_single_run_writes_its_result_and_prints_commands_that_paste_as_is(
    fakes, tmp_path, capsys, loader
):
    # -r runs one checked job wherever it stands; paths with spaces and accents paste as one
    # argument, and the printed render command loads the scene as the run did
    from relaygs.commands.artifact_models import load_run_scene
    from relaygs.pipeline import ArtifactStore

    outputs = tmp_path / "out dir ü"
    args = ["budget=smoke", *TINY_SCENE, "seed=3", f'paths.outputs="{outputs}"', *loader, "-r"]
    assert run_main(args) == 0
    (run_dir,) = outputs.glob("runs/*")
    (scene_dir,) = outputs.glob("scenes/juggle-*")
    result = json.loads((run_dir / "result.json").read_text())
    assert result["seed"] == 3 and result["job"] is None
    assert result["scene.frames"] == 3  # every override is recorded by its dotted key
    assert list(run_dir.glob("events.out.tfevents.*"))  # TensorBoard's run: the folder
    assert not (run_dir / "run.log").exists()  # the app prints: it would stay empty
    assert (outputs / "artifacts" / "deform").is_dir()
    lines = [line.strip() for line in capsys.readouterr().out.splitlines()]
    tensorboard = shlex.split(next(line for line in lines if line.startswith("tensorboard ")))
    assert tensorboard[1:] == [script_command("tensorboard"), "--logdir", str(run_dir)]
    ply = shlex.split(next(line for line in lines if line.startswith("ply ")))
    assert ply[ply.index("--root") + 1] == str(outputs / "artifacts")
    videos = shlex.split(next(line for line in lines if line.startswith("videos ")))
    args = artifacts_parser().parse_args(videos[videos.index("relaygs.artifacts") + 1 :])
    assert (args.root, args.scene) == (outputs / "artifacts", scene_dir)
    item = ArtifactStore(args.root).find(args.key)
    trained = item.manifest.provenance["scene"]
    assert load_run_scene(args, item).fingerprint == trained  # so `eval` and `render` add no note
    args.test_cameras = args.downscale = None  # as typed without them: the manifest's record
    assert load_run_scene(args, item).fingerprint == trained


class _FlushLog(io.StringIO):
    """Stdout that keeps what had been written at each flush, as a log file would show it."""

    def __init__(self) -> None:
        super().__init__()
        self.flushed: list[str] = []

    def flush(self) -> None:
        self.flushed.append(self.getvalue())


def test_each_stage_line_and_a_jobs_summary_reach_the_log_when_printed(
    fakes, tmp_path, monkeypatch
):
    log = _FlushLog()
    monkeypatch.setattr(sys, "stdout", log)
    assert run_main(["budget=smoke", *TINY_SCENE, "seed=3,4", "-m"]) == 0  # -m may come last
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    assert sorted(pd.read_csv(sweep / "summary.csv").seed) == [3, 4]
    ends = [text.rstrip("\n").rsplit("\n", 1)[-1] for text in log.flushed]
    for node in ("decouple", "relay", "deform"):
        assert any(end.startswith(f"[{node}] built {node} artifact") for end in ends), node
    assert any(end.startswith("[eval] evaluated the test views") for end in ends)
    jobs_done = [end for end in ends if end.lstrip().startswith("videos ")]
    assert len(set(jobs_done)) == 2  # job 0's summary is out before job 1 starts


@pytest.mark.parametrize("args", [[], ["+experiment=ablation_k"]])
def test_a_full_disk_refusing_hydras_own_files_is_one_line_not_a_traceback(
    fakes, tmp_path, capsys, monkeypatch, args
):
    # Hydra writes each job's .hydra/*.yaml (and a sweep's multirun.yaml) before the job runs
    import hydra.core.utils

    def full(cfg, filename, output_dir):
        output_dir.mkdir(parents=True, exist_ok=True)
        (output_dir / filename).touch()  # opened, then the write fails: a 0-byte file
        raise OSError(errno.ENOSPC, "No space left on device", str(output_dir / filename))

    monkeypatch.setattr(hydra.core.utils, "_save_config", full)
    assert run_main(["budget=smoke", *TINY_SCENE, *args]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("error: No space left on device writing ") and ".yaml" in err
    assert "HYDRA_FULL_ERROR" not in os.environ
    assert fakes.ran("decouple") == 0


def test_ablation_k_sweep_shares_decouple_and_writes_the_summary(fakes, tmp_path):
    assert run_main(["+experiment=ablation_k", "budget=smoke", *TINY_SCENE]) == 0
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    table = pd.read_csv(sweep / "summary.csv")
    assert list(table.variant) == ["k8", "k16", "k32", "k64", "k128"]
    assert list(table["relay.k"]) == [8, 16, 32, 64, 128]
    assert table.loc[table.variant == "k16", "delta_psnr"].item() == 0.0
    assert fakes.ran("decouple") == 1 and fakes.ran("relay") == 5
    assert list(table.cache_hits) == [0, 1, 1, 1, 1]
    assert sorted(p.name for p in sweep.iterdir() if p.is_dir())[:2] == ["0_k8", "1_k16"]
    assert (sweep / "summary.md").is_file() and (sweep / "pareto.png").is_file()


def test_components_sweep_builds_each_distinct_upstream_once(fakes, tmp_path):
    assert run_main(["+experiment=ablation_components", "budget=smoke", *TINY_SCENE]) == 0
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    table = pd.read_csv(sweep / "summary.csv")
    components = "full no_copies no_stage2 no_pseudo_views no_isolation no_gamma"
    assert list(table.variant) == components.split()
    assert list(table.pipeline) == ["relaygs", "no_copies", "no_stage2", *["relaygs"] * 3]
    built = {stage: fakes.ran(stage) for stage in ("decouple", "relay", "replicate", "deform")}
    assert built == {"decouple": 1, "relay": 2, "replicate": 1, "deform": 6}


def test_the_command_line_fails_in_one_line_in_a_fresh_process(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "relaygs.run", "pipeline=nope"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "pipeline/nope" in lines[0], done.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("overrides", "jobs"),
    [
        (["relay.k=8,16", "seed=0"], [["relay.k=8", "seed=0"], ["relay.k=16", "seed=0"]]),
        (["seed=range(0,2)", "a=[1,2]"], [["seed=0", "a=[1,2]"], ["seed=1", "a=[1,2]"]]),
        (
            ["+c=x,y", "~d", "e='a b'"],
            [["+c=x", "~d=null", "e='a b'"], ["+c=y", "~d=null", "e='a b'"]],
        ),
        (["relay.k=8,16", "relay.k=32"], [["relay.k=32"]]),  # the command line over params
    ],
)
def test_sweep_jobs_are_the_basic_sweepers_combinations(overrides, jobs):
    assert prelaunch.sweep_jobs(prelaunch.parse_overrides(overrides)) == jobs


def test_an_interval_sweep_is_one_line_naming_it():
    with refused(InputError, "k=interval(0,1)"):
        prelaunch.sweep_jobs(prelaunch.parse_overrides(["k=interval(0,1)"]))


def test_nothing_imports_hydras_private_modules():
    for path in Path(prelaunch.__file__).parents[1].rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [getattr(node, "module", None) or "", *(alias.name for alias in node.names)]
                private = [name for name in names if name.split(".")[:2] == ["hydra", "_internal"]]
                assert not private, path
