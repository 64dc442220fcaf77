"""`python -m relaygs.bench sweeps`: the commands it times and how it reports a failing one."""

from relaygs import bench, bench_sweeps


def test_commands_run_each_experiment_on_the_tiny_scene(tmp_path):
    line = bench_sweeps.command("baseline", tmp_path, "seed=3")
    assert line[1:4] == ["-m", "relaygs.run", "+experiment=baseline"]
    assert all(override in line for override in bench_sweeps.TINY_SCENE)
    assert line[-2:] == ["seed=3", f"paths.outputs={tmp_path}"]


def test_a_failing_experiment_is_named_and_exits_non_zero(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(bench_sweeps, "EXPERIMENTS", ("no_such_experiment",))
    report = tmp_path / "report.json"
    code = bench.main(["sweeps", "--outputs", str(tmp_path / "out"), "--json", str(report)])
    assert code == 1
    assert "experiment 'no_such_experiment' exited" in capsys.readouterr().err
    assert not report.exists()
