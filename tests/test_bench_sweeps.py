"""`python -m relaygs.bench sweeps`: the commands it times and how it reports a failing one;
the other subcommands' options and `bench field`'s and `bench hull`'s reports."""

import json
import subprocess

import pytest

from relaygs.commands import (
    bench,
    bench_field,
    bench_hull,
    bench_splat,
    bench_sweeps,
    bench_train,
)


@pytest.fixture
def no_work(monkeypatch):
    """Any bench that starts measuring fails the test: a refusal comes before any work."""
    work = [(bench_sweeps, "time_experiments"), (bench_train, "bench_scene")]
    work += [(bench_splat, "bench_splat"), (bench_field, "_field_step")]
    work += [(bench_hull, "_hull_step")]
    for module, name in work:
        monkeypatch.setattr(module, name, lambda *args, name=name: pytest.fail(f"{name} ran"))


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["splat", "--repeats", "0"], "argument --repeats: expected an integer >= 1, got '0'"),
        (["train", "--steps", "0"], "argument --steps: expected an integer >= 2, got '0'"),
        (["train", "--threads", "-4"], "argument --threads: expected an integer >= 1, got '-4'"),
        (["foo"], "argument command: invalid choice: 'foo'"),
        (["splat", "--backends", "torch,fast"], "'fast'"),
        (["train", "--backends", "torch,fast"], "'fast'"),
        (["field", "--backends", "torch,fast"], "'fast'"),
        (["field", "--widths", "64", "0"], "--widths"),
        (["hull", "--copy", "0"], "--copy"),
        (["hull", "--backends", "torch,fast"], "'fast'"),
        (["train", "--device", "cuda:99"], "--device"),
        (["train", "--device", "tpu"], "'tpu'"),
        # a file where the report's folder should be
        (["splat", "--json", "taken/report.json"], "taken is not a folder"),
        (["train", "--json", "taken/report.json"], "taken is not a folder"),
        (["sweeps", "--json", "taken/report.json"], "taken is not a folder"),
    ],
)
def test_bad_options_are_refused_in_one_line_before_any_work(
    argv, named, no_work, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "taken").write_text("")
    try:
        code = bench.main(argv)
    except SystemExit as stopped:  # argparse's usage error
        code = stopped.code
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and named in err and err.count("\n") == 1


def test_experiments_run_on_the_tiny_scene_and_a_failing_one_is_named_by_its_error(
    tmp_path, monkeypatch, capsys
):
    stderr = (
        "Traceback (most recent call last):\n  ...\n"
        "error: paths.outputs: cannot create /proc/x\n"
        "Set the environment variable HYDRA_FULL_ERROR=1 for a complete stack trace.\n"
    )
    failed = subprocess.CompletedProcess([], 1, stdout="", stderr=stderr)
    monkeypatch.setattr(bench_sweeps.subprocess, "run", lambda *args, **kwargs: failed)
    report = tmp_path / "report.json"
    assert bench.main(["sweeps", "--outputs", str(tmp_path / "out"), "--json", str(report)]) == 1
    assert capsys.readouterr().err == (
        "error: experiment 'smoke' exited 1: paths.outputs: cannot create /proc/x\n"
    )
    assert not report.exists()
    # without an error line: the last line that is not Hydra's hint
    assert bench_sweeps.failure_line(f"boom\n{stderr.splitlines()[-1]}\n") == "boom"
    assert bench_sweeps.failure_line("") == "(no output)"
    # each experiment runs on the tiny scene
    line = bench_sweeps.command("baseline", tmp_path, "seed=3")
    assert line[1:4] == ["-m", "relaygs.run", "+experiment=baseline"]
    assert all(override in line for override in bench_sweeps.TINY_SCENE)
    assert line[-2:] == ["seed=3", f"paths.outputs={tmp_path}"]


def test_bench_field_times_each_backend_and_restores_the_process_backend(tmp_path, capsys):
    from relaygs.splat import default_backend

    before = default_backend()
    report = tmp_path / "field.json"
    argv = ["field", "--gaussians", "300", "--repeats", "2", "--threads", "1"]
    assert bench.main([*argv, "--backends", "torch,auto", "--json", str(report)]) == 0
    figures = json.loads(report.read_text())
    assert figures["gaussians"] == 300 and figures["threads"] == 1
    small = bench_field.small_field_settings()
    small_mlp = bench_field.variant_label(small["width"], small["matmul_dtype"])
    assert list(figures["fwd_bwd_ms"]) == [small_mlp]  # the `small` budget's field
    assert set(figures["fwd_bwd_ms"][small_mlp]) == {"torch", "auto"}
    assert all(ms > 0 for ms in figures["fwd_bwd_ms"][small_mlp].values())
    assert "ratio" in capsys.readouterr().out
    assert default_backend() == before

    variants = ["--widths", "16", "8", "--matmul-dtypes", "float32", "bfloat16"]
    assert bench.main([*argv, *variants, "--json", str(report)]) == 0
    rows = ["16 float32", "16 bfloat16", "8 float32", "8 bfloat16"]
    assert list(json.loads(report.read_text())["fwd_bwd_ms"]) == rows
    assert "vs torch at 16 float32" in capsys.readouterr().out


def test_bench_hull_times_each_backend_and_restores_the_process_backend(tmp_path, capsys):
    from relaygs.splat import default_backend

    before = default_backend()
    report = tmp_path / "hull.json"
    argv = ["hull", "--copy", "50", "--hull", "70", "--repeats", "2", "--threads", "1"]
    assert bench.main([*argv, "--backends", "torch,auto", "--json", str(report)]) == 0
    figures = json.loads(report.read_text())
    assert (figures["copy"], figures["hull"], figures["threads"]) == (50, 70, 1)
    assert set(figures["fwd_bwd_ms"]) == {"torch", "auto"}
    assert all(ms > 0 for ms in figures["fwd_bwd_ms"].values())
    assert "ratio" in capsys.readouterr().out
    assert default_backend() == before


def test_bench_train_reports_each_stage_at_its_median_round():
    rounds = [
        [{"stage": "relay", "steps": 30, "steps_per_s": speed, "gaussians": 9}]
        for speed in (4.0, 9.0, 5.0)
    ]
    (row,) = bench_train.median_rows(rounds)
    assert row == {"stage": "relay", "steps": 30, "steps_per_s": 5.0, "gaussians": 9,
                   "runs": [4.0, 9.0, 5.0]}  # fmt: skip

    faster = [[{**row, "steps_per_s": 2.0 * row["steps_per_s"]}] for (row,) in rounds]
    stages = {"torch": bench_train.median_rows(rounds), "auto": bench_train.median_rows(faster)}
    assert bench_train.median_speedups(stages, ["torch", "auto"]) == [2.0]
