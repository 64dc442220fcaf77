"""A job that raises: its result.json records the failure, the rest of a sweep still runs, the
summary lists the finished jobs and the failed one, and the command exits 1."""

import errno
import json
import pickle
import shutil

import pandas as pd
import pytest
from filelock import FileLock
from omegaconf import OmegaConf

from conftest import run_main
from fake_stages import TINY_SCENE
from relaygs.app import callbacks
from relaygs.app import task as task_module
from relaygs.app.callbacks import SWEEP_LOCK_FILE, SweepFolderLock
from relaygs.commands import report

ERROR = "RuntimeError: relay diverged: loss is nan"


def _relay_k_is(k):
    return lambda stage, cfg: stage == "relay" and cfg["relay"]["k"] == k


def test_a_failing_job_leaves_a_summary_of_the_sweep_and_exit_status_1(fakes, tmp_path, capsys):
    fakes.fail_when = _relay_k_is(16)
    args = ["-m", "relay.k=8,16,32", "variant=k${relay.k}", "budget=smoke", *TINY_SCENE]
    assert run_main(args) == 1
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    result = json.loads((sweep / "1_k16" / "result.json").read_text())
    assert (result["status"], result["error"]) == ("failed", ERROR)
    assert (result["pipeline"], result["relay.k"], result["psnr"]) == ("relaygs", 16, None)
    assert result["job_s"] > 0
    table = pd.read_csv(sweep / "summary.csv")
    assert list(table.variant) == ["k8", "k16", "k32"]
    assert list(table.status) == ["ok", "failed", "ok"]
    assert table.psnr.notna().tolist() == [True, False, True]
    assert table.error[1] == ERROR and table.error.isna()[[0, 2]].all()
    assert fakes.ran("deform") == 2  # the job after the failed one still ran
    markdown = (sweep / "summary.md").read_text()
    assert "| k16 (failed) | n/a |" in markdown
    assert f"1 of 3 job(s) failed:\n\n- job 1 (k16): {ERROR}\n" in markdown
    assert (sweep / "pareto.png").is_file()
    out, err = capsys.readouterr()
    assert out.count("job 1 (k16): ") == 1  # in the printed table's list, not again below it
    assert f"error: job 1 failed: {ERROR}" in err
    assert "Traceback" in err  # an unexpected error shows where it happened
    assert err.strip().splitlines()[-1] == f"error: 1 of 3 job(s) failed: job 1 (k16): {ERROR}"
    assert report.main([str(sweep)]) == 0  # rewriting the report lists the failure again
    assert capsys.readouterr().out.count("job 1 (k16): " + ERROR) == 1


def test_a_sweep_in_a_folder_of_an_earlier_one_names_its_jobs_and_skips_its_failures(
    fakes, tmp_path, capsys
):
    fakes.fail_when = _relay_k_is(16)
    folder = tmp_path / "sweep"
    common = ["variant=k${relay.k}", "budget=smoke", f"hydra.sweep.dir={folder}", *TINY_SCENE]
    assert run_main(["-m", "relay.k=8,16", *common]) == 1
    capsys.readouterr()
    # the failed job is the earlier sweep's, not this one's
    assert run_main(["-m", "relay.k=32", *common]) == 0
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == (
        f"note: the summary also holds 2 job(s) of an earlier sweep in {folder}: 0_k8, 1_k16; "
        "give each sweep its own hydra.sweep.dir"
    )
    assert list(pd.read_csv(folder / "summary.csv").variant) == ["k32", "k8", "k16"]


RERUN = "rerun the same command (finished stages are reused"
ENVIRONMENT_FAILURES = [
    pytest.param(
        OSError(errno.ENOSPC, "No space left on device", "/store/x.safetensors"),
        "stage relay: No space left on device writing /store/x.safetensors: free space, then",
        id="disk-full",
    ),
    pytest.param(
        OSError(errno.EDQUOT, "Disk quota exceeded", "/store/x.safetensors"),
        "stage relay: Disk quota exceeded writing /store/x.safetensors: free space, then",
        id="quota",
    ),
    pytest.param(
        OSError(errno.EROFS, "Read-only file system", "/store/relay"),
        "stage relay: cannot write /store/relay (Read-only file system): make it writable, then",
        id="read-only",
    ),
    pytest.param(
        PermissionError(errno.EACCES, "Permission denied", "/store/relay"),
        "stage relay: cannot access /store/relay (Permission denied): give this user access",
        id="permission",
    ),
    pytest.param(
        PermissionError(errno.EPERM, "Operation not permitted", "/store/relay"),
        "stage relay: cannot access /store/relay (Operation not permitted): give this user",
        id="not-permitted",
    ),
    pytest.param(MemoryError(), "stage relay: out of memory: free memory", id="memory-error"),
    pytest.param(
        RuntimeError("DefaultCPUAllocator: can't allocate memory: you tried to allocate 8 bytes"),
        "stage relay: out of memory: free memory",
        id="cpu-allocator",
    ),
]


def _raise_in_relay(error):
    def fail_when(stage, cfg):
        if stage == "relay" and cfg["relay"]["k"] != 4:
            raise error
        return False

    return fail_when


@pytest.mark.parametrize(("error", "message"), ENVIRONMENT_FAILURES)
def test_a_run_out_of_disk_or_memory_ends_in_one_line_and_records_it(
    fakes, tmp_path, capsys, error, message
):
    fakes.fail_when = _raise_in_relay(error)
    assert run_main(["budget=smoke", *TINY_SCENE]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith(f"error: {message}")
    assert RERUN in err
    (result_file,) = tmp_path.glob("outputs/runs/*/result.json")
    result = json.loads(result_file.read_text())
    assert result["status"] == "failed" and result["error"].startswith(f"ResourceError: {message}")


def test_a_programming_error_in_a_run_keeps_its_traceback(fakes, capsys):
    fakes.fail_when = _raise_in_relay(FileNotFoundError(errno.ENOENT, "gone", "/x"))
    assert run_main(["budget=smoke", *TINY_SCENE]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "FileNotFoundError" in err


def test_a_sweep_job_out_of_disk_is_recorded_in_one_line_and_the_others_run(
    fakes, tmp_path, capsys
):
    full = OSError(errno.ENOSPC, "No space left on device", "/store/x.safetensors")
    fakes.fail_when = _raise_in_relay(full)
    args = ["-m", "relay.k=2,4", "variant=k${relay.k}", "budget=smoke", *TINY_SCENE]
    assert run_main(args) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = "ResourceError: stage relay: No space left on device writing /store/x.safetensors"
    assert f"error: job 0 failed: {line}" in err
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    table = pd.read_csv(sweep / "summary.csv")
    assert list(table.status) == ["failed", "ok"]
    assert table.error[0].startswith(line)
    assert fakes.ran("deform") == 1  # the job after the failed one still ran


def test_a_sweep_started_in_the_folder_of_a_running_one_stops_before_any_job(
    fakes, tmp_path, capsys
):
    # before, both wrote the same job folders: the result.json files of one were lost
    folder = tmp_path / "sweep"
    folder.mkdir()
    args = ["-m", "relay.k=2,4", "budget=smoke", f"hydra.sweep.dir={folder}", *TINY_SCENE]
    with FileLock(folder / SWEEP_LOCK_FILE):  # held as the running sweep's process holds it
        assert run_main(args) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"error: another sweep is running in {folder}: wait for it to end, or give this one "
        "its own hydra.sweep.dir"
    ]
    assert fakes.calls == [] and not list(folder.rglob("result.json"))
    assert run_main(args) == 0  # once that sweep has ended
    assert len(list(folder.rglob("result.json"))) == 2
    with FileLock(folder / SWEEP_LOCK_FILE).acquire(timeout=0):  # which leaves the folder free
        pass


def test_a_sweep_holding_its_folder_goes_to_parallel_workers_without_the_lock(tmp_path):
    # the joblib launcher pickles Hydra's callbacks with every job
    callback = SweepFolderLock()
    callback.on_multirun_start(OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}}))
    worker_copy = pickle.loads(pickle.dumps(callback))
    worker_copy.on_multirun_end(OmegaConf.create({}))  # a worker's copy releases nothing
    with pytest.raises(SystemExit):  # the launching process still holds the folder
        SweepFolderLock().on_multirun_start(
            OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}})
        )
    callback.on_multirun_end(OmegaConf.create({}))
    with FileLock(tmp_path / SWEEP_LOCK_FILE).acquire(timeout=0):
        pass


def test_a_sweep_job_on_damaged_scene_data_fails_alone_even_over_an_earlier_good_result(
    fakes, tmp_path, tiny_synth_scene, capsys
):
    damaged = shutil.copytree(tiny_synth_scene, tmp_path / "damaged")
    folder = tmp_path / "sweep"
    scenes = f"scene.path={damaged},{tiny_synth_scene}"
    args = ["-m", scenes, "budget=smoke", f"hydra.sweep.dir={folder}"]
    assert run_main(args) == 0
    image = next(damaged.glob("ims/*/000001.png"))
    image.unlink()
    fakes.calls.clear()
    assert run_main(args) == 1  # not 0 on job 0's earlier result
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"error: job 0 failed: InputError: missing image file: {image}" in err
    table = pd.read_csv(folder / "summary.csv")
    assert list(table.status) == ["failed", "ok"]
    assert fakes.ran("decouple") == 0  # job 1 reused the first sweep's artifacts


def test_a_sweep_job_that_cannot_record_its_failure_stops_the_sweep(fakes, monkeypatch, capsys):
    # an earlier sweep's result in the job's folder is no record of this job's failure
    args = ["-m", "relay.k=2,4", "budget=smoke", "hydra.sweep.dir=sweep", *TINY_SCENE]
    assert run_main(args) == 0
    full = OSError(errno.ENOSPC, "No space left on device", "/store/x.safetensors")

    def refuse_failed(run_dir, result):
        raise full

    monkeypatch.setattr(task_module, "write_result", refuse_failed)
    fakes.calls.clear()
    fakes.fail_when = _raise_in_relay(full)
    assert run_main([*args, "relay.steps=3"]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].startswith("error: stage relay: No space left on device")
    assert "job 0 failed" not in err and fakes.ran("relay") == 1  # job 1 never started


def test_a_sweep_whose_summary_cannot_be_written_exits_1(fakes, monkeypatch, capsys):

    def broken(sweep_dir):
        raise KeyError("psnr")

    monkeypatch.setattr(callbacks, "write_reports", broken)
    args = ["-m", "relay.k=2,4", "budget=smoke", *TINY_SCENE]
    assert run_main(args) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err  # not a relaygs error: where it happened is shown
    assert err.strip().splitlines()[-1] == "error: no sweep summary: KeyError: 'psnr'"


def test_the_report_of_a_half_finished_sweep_counts_the_jobs_it_lacks(fakes, tmp_path, capsys):
    args = ["-m", "relay.k=8,16,32", "variant=k${relay.k}", "budget=smoke", *TINY_SCENE]
    assert run_main([*args, "hydra.sweep.dir=sweep"]) == 0
    # as a sweep stopped in job 1 leaves it: job 1 started (Hydra's .hydra/), job 2 did not
    (tmp_path / "sweep" / "1_k16" / "result.json").unlink()
    shutil.rmtree(tmp_path / "sweep" / "2_k32")
    capsys.readouterr()
    assert report.main([str(tmp_path / "sweep")]) == 0
    out = capsys.readouterr().out
    assert (
        "Not in the table: 1 run folder(s) hold no result.json (interrupted, still running or "
        "stopped before writing it): 1_k16; 1 of the 3 job(s) the sweep planned have no folder "
        "(not started).\n"
    ) in out


def test_jobs_in_nested_folders_count_as_started(fakes, tmp_path):
    subdir = "hydra.sweep.subdir=s${seed}/j${hydra.job.num}"
    args = ["-m", "seed=0,1", "budget=smoke", "hydra.sweep.dir=sweep", subdir, *TINY_SCENE]
    assert run_main(args) == 0
    assert "Not in the table" not in (tmp_path / "sweep" / "summary.md").read_text()


@pytest.mark.parametrize(
    "record",
    [
        "hydra: {sweeper: {_target_: plugins.BasicSweeper}, overrides: {task: null}}",
        "hydra: {sweeper: basic, overrides: {task: [seed=0]}}",
        "hydra: [1, 2]",
        "{{not yaml",
    ],
)
def test_a_multirun_record_the_count_cannot_read_leaves_the_report_whole(tmp_path, record):
    (tmp_path / "0_k8").mkdir()
    result = {"variant": "k8", "job": 0, "pipeline": "relaygs", "scene": "s", "seed": 0, "psnr": 20}
    (tmp_path / "0_k8" / "result.json").write_text(json.dumps(result))
    (tmp_path / "multirun.yaml").write_text(record)
    assert report.main([str(tmp_path)]) == 0
    assert "Not in the table" not in (tmp_path / "summary.md").read_text()
