"""Sweep reports: summary.csv and summary.md rows with Δ vs the reference, Pareto plot, CLI."""

import json
import os
import re
from pathlib import Path

import pandas as pd
import pytest

from refusals import refused
from relaygs.app import pareto
from relaygs.app.pareto import pareto_front, point_labels
from relaygs.app.summary import summary_table
from relaygs.commands import report
from relaygs.errors import InputError
from sweep_jobs import PNG_SIGNATURE
from sweep_jobs import write_job as _job


def _row(markdown: str, *first: str) -> list[str]:
    """The cells of the one Markdown table row whose leading cells are `first`."""
    rows = [
        [cell.strip() for cell in line.strip().strip("|").split(" | ")]
        for line in markdown.splitlines()
        if line.startswith("| ")
    ]
    (row,) = [row for row in rows if row[: len(first)] == list(first)]
    return row


def _refused(capsys, folder: Path, *named: str) -> str:
    """Run `report FOLDER`, expect exit 1 with one error line naming each of `named`."""
    assert report.main([str(folder)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert all(name in err for name in named), (err, named)
    return err


def _figures(markdown: str, start: str) -> list[str]:
    """The numbers in the one line of `markdown` that starts with `start`."""
    (line,) = [line for line in markdown.splitlines() if line.startswith(start)]
    return re.findall(r"\d+(?:\.\d+)?", line)


@pytest.fixture
def sweep(tmp_path):
    for number, (variant, psnr, seconds) in enumerate(
        [("k8", 25.0, 30.0), ("k16", 26.0, 20.0), ("k32", 24.5, 10.0), ("k64", 23.0, 12.0)]
    ):
        _job(tmp_path, number, variant, psnr, seconds)
    return tmp_path


def test_reports_have_one_row_per_job_with_delta_vs_reference(sweep, tmp_path):
    files = report.write_reports(sweep)
    table = pd.read_csv(files.csv)
    assert list(table.variant) == ["k8", "k16", "k32", "k64"]
    assert list(table.delta_psnr) == pytest.approx([-1.0, 0.0, -1.5, -3.0])
    assert list(table.columns[:6]) == ["job", "variant", "pipeline", "scene", "seed", "psnr"]
    assert "relay.k" in table.columns
    markdown = files.markdown.read_text()
    assert markdown.startswith("# ablation_k on juggle")
    assert _row(markdown, "k32")[1:6] == ["24.50", "-1.50", "n/a", "n/a", "0.8000"]
    assert markdown.count("\n| k") == 4
    assert files.pareto.read_bytes().startswith(PNG_SIGNATURE)
    # each job computed half of its lineage's seconds: 36 s of 72 s
    assert _figures(markdown, "Stage time") == ["36", "72", "0.50"]
    assert "With evaluation" not in markdown  # results from before evaluations were stored
    assert files.mean is None and not (sweep / "summary_mean.csv").exists()  # no repeats
    # a whole-number column with a missing row is written without a decimal point
    _job(sweep, 4, "k4", 22.0, 8.0, **{"relay.k": None})
    lines = report.write_reports(sweep).csv.read_text().splitlines()
    header = lines[0].split(",")
    column = header.index("relay.k")
    assert [line.split(",")[column] for line in lines[1:]] == ["8", "16", "32", "64", ""]
    assert lines[1].split(",")[header.index("psnr")] == "25.0"
    # the title names the experiment only when every job ran it
    single = {"experiment": None, "job": None}  # what a single run's result.json holds
    _job(sweep, 5, "k128", 20.0, 5.0, **single)  # copied in beside the sweep's jobs
    report.write_reports(sweep)
    assert (sweep / "summary.md").read_text().startswith(f"# {sweep.name} on juggle")
    runs = tmp_path / "runs"
    for number, variant in enumerate(("k8", "k16")):
        _job(runs, number, variant, 20.0, 5.0, **single)
    report.write_reports(runs)
    assert (runs / "summary.md").read_text().startswith("# runs on juggle")


UNLABELLED = {"reference_variant": None}


@pytest.mark.parametrize(
    ("jobs", "deltas"),
    [
        # the reference job of the row's seed; none at seed 2: the mean of all
        (
            [
                ("k16", 26.0, {}),
                ("k16", 28.0, {"seed": 1}),
                ("k8", 27.0, {"seed": 1}),
                ("k32", 27.0, {"seed": 2}),
            ],
            [0.0, 0.0, -1.0, 0.0],
        ),
        # runs labelled k16 at k = 16 and 128: a row takes the reference at its own k (their
        # mean at a k none has), the reference variant's row at k = 128 its first job
        (
            [
                ("k16", 26.0, {"relay.k": 16}),
                ("k16", 27.0, {"relay.k": 128}),
                ("k8", 25.0, {"relay.k": 16}),
                ("k8", 27.5, {"relay.k": 128}),
                ("k32", 25.0, {}),
            ],
            [0.0, 1.0, -1.0, 0.5, -1.5],
        ),
        # `-m relay.k=1,2 seed=0,1` without labels: each job against job 0 of its seed
        (
            [
                ("k1", psnr, {**UNLABELLED, "relay.k": k, "seed": seed})
                for k, seed, psnr in ((1, 0, 25.0), (2, 0, 24.0), (1, 1, 26.0), (2, 1, 27.0))
            ],
            [0.0, -1.0, 0.0, 1.0],
        ),
        ([("k8", 25.0, UNLABELLED), ("k16", 26.5, UNLABELLED)], [0.0, 1.5]),
    ],
)
def test_delta_compares_with_the_reference_job_that_matches_the_row(tmp_path, jobs, deltas):
    for number, (variant, psnr, extra) in enumerate(jobs):
        _job(tmp_path, number, variant, psnr, 10.0, **extra)
    table = summary_table(report.collect_results(tmp_path))
    assert list(table.delta_psnr) == pytest.approx(deltas)


def test_delta_compares_only_runs_scored_on_the_same_images(tmp_path, capsys):
    # `report outputs/runs` over runs at two downscales: each compares within its test set
    _job(tmp_path, 0, "k16", 26.0, 20.0, test_set="full")
    _job(tmp_path, 1, "k16", 30.0, 20.0, test_set="half")
    _job(tmp_path, 2, "k8", 25.0, 10.0, test_set="full")
    _job(tmp_path, 3, "k8", 31.0, 10.0, test_set="half")
    _job(tmp_path, 4, "k32", 24.0, 10.0, test_set="other")  # no k16 run on its images
    _job(tmp_path, 5, "k32", 24.0, 10.0, scene="court")  # nor on its scene
    _job(tmp_path, 6, "k64", 29.0, 10.0)  # written before results named their test set
    table = summary_table(report.collect_results(tmp_path))
    assert list(table.delta_psnr[:4]) == pytest.approx([0.0, 0.0, -1.0, 1.0])
    assert table.delta_psnr[4:6].isna().all()
    assert table.delta_psnr[6] == pytest.approx(1.0)  # against both k16 runs on juggle
    files = report.write_reports(tmp_path)
    markdown = files.markdown.read_text()
    assert _figures(markdown, "Δ PSNR is n/a for")[:4] == ["4", "32", "5", "32"]
    assert files.mean is None  # no two jobs differ only in their seed
    _job(tmp_path, 7, "k16", 28.0, 20.0, test_set="full", seed=1)
    mean = report.write_reports(tmp_path).mean.read_text()
    # nor do the means average PSNR over different images; one run has no spread
    assert mean.splitlines()[2].startswith("| Scene | Variant | Test set | Runs | PSNR")
    assert _row(mean, "juggle", "k16", "full")[3:5] == ["2", "27.00 ± 1.41"]
    assert _row(mean, "juggle", "k16", "half")[3:6] == ["1", "30.00", "0.00"]


def test_the_summary_names_run_folders_that_hold_no_result(tmp_path, capsys):
    # an interrupted sweep: job 1 started (Hydra wrote its .hydra/) but never finished
    (tmp_path / "1_k16" / ".hydra").mkdir(parents=True)
    assert _refused(capsys, tmp_path, str(tmp_path), "result.json").endswith(": 1_k16)\n")
    run = tmp_path / "1_k16"  # `report RUN_DIR` of that run: the folder by its path, not "."
    assert _refused(capsys, run).endswith(f": {run})\n")
    _job(tmp_path, 0, "k8", 25.0, 10.0)
    for number in range(2, 8):
        (tmp_path / f"{number}_k{number}" / ".hydra").mkdir(parents=True)
    markdown = report.write_reports(tmp_path).markdown.read_text()
    (absent,) = [line for line in markdown.splitlines() if line.startswith("Not in the table")]
    assert absent.startswith("Not in the table: 7 ") and absent.endswith(" 5_k5 and 2 more.")
    run = tmp_path / "0_k8"  # a finished run's own folder is not taken for a sweep
    _refused(capsys, run, str(run), "result.json")
    assert sorted(p.name for p in run.iterdir()) == ["result.json"]


def test_the_summary_says_which_jobs_share_one_model_or_a_stage_note(tmp_path):
    # ablation_k on an 8-frame scene: k = 8 ... 128 are one segment, one relay/deform lineage
    note = "[decouple] decouple marked no Gaussian as foreground"
    for number, variant in enumerate(["k8", "k16", "k32"]):
        noted = {"notes": note} if number != 1 else {}
        _job(tmp_path, number, variant, 25.0, 10.0, output_key="ab12cd34" + "0" * 56, **noted)
    _job(tmp_path, 3, "k4", 26.0, 10.0, output_key="ef56" + "0" * 60)
    _job(tmp_path, 4, "k2", None, 10.0, status="failed", output_key=None)
    markdown = report.write_reports(tmp_path).markdown.read_text()
    assert (
        "\nSame trained model for job 0 (k8), job 1 (k16), job 2 (k32) (artifact ab12cd34): "
        "their settings train the same model on this scene (every relay.k at or above the "
        "scene's frame count is one segment)\n"
    ) in markdown
    assert markdown.count("Same trained model") == 1
    assert f"\nNote for job 0 (k8), job 2 (k32): {note}\n" in markdown
    for number, variant in ((1, "k16"), (3, "k4"), (4, "k2")):
        (tmp_path / f"{number}_{variant}" / "result.json").unlink()
    markdown = report.write_reports(tmp_path).markdown.read_text()
    assert f"\nNote for every job: {note}\n" in markdown


def test_a_folder_of_sweeps_names_each_jobs_sweep(tmp_path):
    # `report outputs/sweeps`: two sweeps of the same experiment, jobs numbered alike
    # folder names sort "10_k8" before "2_k16"; the rows follow the job numbers
    _job(tmp_path / "sw2", 2, "k16", 26.0, 20.0)
    _job(tmp_path / "sw2", 10, "k8", 25.5, 10.0)
    _job(tmp_path / "sw1", 1, "k8", 25.0, 10.0)
    _job(tmp_path / "sw1", 0, "k16", 27.0, 20.0)
    _job(tmp_path, 2, "k32", None, 10.0, status="failed", error="RuntimeError: x")
    files = report.write_reports(tmp_path)
    table = pd.read_csv(files.csv)
    rows = list(zip(table.sweep, table.job, table.delta_psnr.fillna(0.0), strict=True))
    # Δ against the reference job of the row's own sweep
    assert rows == [
        (".", 2, 0.0),
        ("sw1", 0, 0.0),
        ("sw1", 1, -2.0),
        ("sw2", 2, 0.0),
        ("sw2", 10, -0.5),
    ]
    markdown = files.markdown.read_text()
    assert "| Variant | sweep | relay.k | PSNR" in markdown
    assert _row(markdown, "k8", "sw2")[2:5] == ["8", "25.50", "-0.50"]
    assert "- job 2 (k32): RuntimeError: x\n" in markdown
    assert _figures(markdown, "Stage time")[:2] == ["35", "70"]


def test_when_no_job_is_the_reference_the_report_says_why_delta_is_missing(tmp_path, capsys):
    # `+experiment=ablation_k relay.k=8,32` (k16 not swept), or a misspelt report.reference
    _job(tmp_path, 0, "k8", 25.0, 30.0)
    _job(tmp_path, 1, "k32", 24.0, 30.0)
    assert report.main([str(tmp_path)]) == 0
    line = "Δ PSNR is n/a against the reference variant 'k16' (report.reference): no job is"
    out = capsys.readouterr().out
    assert f"{line} that variant; this sweep's variants are k8, k32" in out
    assert out.count(line) == 1  # printed with the table, not again below it
    assert line in (tmp_path / "summary.md").read_text()


def test_the_cli_rewrites_the_table_prints_it_then_where_the_files_are(sweep, tmp_path, capsys):
    (sweep / "summary.md").write_text("stale")
    assert report.main([str(sweep)]) == 0
    out = capsys.readouterr().out
    table, files = out.split("\nsummary of 4 job(s):\n")
    assert table.rstrip("\n") == (sweep / "summary.md").read_text().rstrip("\n")
    assert table.startswith("# ablation_k") and "Δ PSNR is n/a" not in table  # k16 ran
    *written, board = files.strip("\n").splitlines()
    assert [line.strip() for line in written] == [
        str(sweep / name) for name in ("summary.md", "summary.csv", "pareto.png")
    ]
    assert board.split()[0] == str(sweep / "sweep") and "TensorBoard run `sweep`" in board
    empty = tmp_path / "empty"
    empty.mkdir()
    assert report.main([str(empty)]) == 1
    assert report.main([str(tmp_path / "missing")]) == 1
    assert report.main([str(sweep / "summary.md")]) == 1
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 3 and all(line.startswith("error: ") for line in errors)
    assert errors[1].endswith("missing does not exist")
    assert errors[2].endswith("summary.md is not a folder")
    # usage errors are one line, and help still works
    with pytest.raises(SystemExit) as caught:
        report.main([])
    err = capsys.readouterr().err
    assert caught.value.code == 2 and err.count("\n") == 1 and "sweep_dir" in err
    with pytest.raises(SystemExit) as caught:
        report.main(["--help"])
    assert caught.value.code == 0 and "usage:" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("times", "scores", "front"),
    [
        ([30, 20, 10, 12], [25, 26, 24.5, 23], [2, 1]),
        ([1, 2, 3], [1, 2, 3], [0, 1, 2]),
        ([1, 1, 2], [5, 6, 6], [1]),
        ([5], [1], [0]),
    ],
)
def test_pareto_front_keeps_only_undominated_jobs(times, scores, front):
    assert pareto_front(times, scores) == front


def test_a_report_being_rewritten_is_never_read_half_written(sweep, monkeypatch):
    # a second sweep sharing the folder, or `report` run beside a sweep, reads the tables while
    # they are rewritten: it must see the previous file or the new one, never part of one
    names = ("summary.md", "summary.csv")
    report.write_reports(sweep)
    before = {name: (sweep / name).read_bytes() for name in names}
    _job(sweep, 4, "k128", 22.0, 8.0)
    seen = []
    write_bytes = Path.write_bytes

    def written_in_two_halves(path, data):
        write_bytes(path, data[: len(data) // 2])
        seen.append({name: (sweep / name).read_bytes() for name in names})
        return write_bytes(path, data)

    def text_in_two_halves(path, text, encoding=None, errors=None, newline=None):
        return written_in_two_halves(path, text.encode(encoding or "utf-8"))

    monkeypatch.setattr(Path, "write_bytes", written_in_two_halves)
    monkeypatch.setattr(Path, "write_text", text_in_two_halves)
    report.write_reports(sweep)
    monkeypatch.undo()
    after = {name: (sweep / name).read_bytes() for name in names}
    assert seen and after != before
    for snapshot in seen:
        for name, content in snapshot.items():
            assert content in (before[name], after[name]), f"{name} was read half-written"
    assert sorted(p.name for p in sweep.iterdir() if p.name.startswith(".")) == []


def test_a_job_folder_that_cannot_be_read_is_named_and_the_tables_stay(sweep, capsys, monkeypatch):
    # chmod 000 on a job folder (simulated: tests run as root): before, the report passed
    # over it and rewrote the tables without that job, with exit 0; a folder removed while
    # the report looks (a running job cleaned it up) is passed over
    vanishing = sweep / "3_k64" / "tmp"
    vanishing.mkdir()
    unreadable = []
    scandir = os.scandir

    def listed(path):
        if Path(path) == vanishing:
            vanishing.rmdir()
        if Path(path) in unreadable:
            raise PermissionError(13, "Permission denied", str(path))
        return scandir(path)

    monkeypatch.setattr(os, "scandir", listed)
    assert report.main([str(sweep)]) == 0
    before = (sweep / "summary.md").read_text()
    unreadable.append(sweep / "2_k32")
    capsys.readouterr()
    _refused(capsys, sweep, str(sweep / "2_k32"), "Permission denied")
    assert (sweep / "summary.md").read_text() == before


def test_repeated_labels_get_the_parameters_that_differ_in_the_table_and_the_means(
    tmp_path, capsys
):
    # `report outputs/runs` over k8 runs at k = 8 and 16, two seeds each (not 4 "seeds"); the
    # whole-number settings that some jobs lack (a synthetic scene: no downscale) read 2
    settings = [(8, 0, 2, 0.2), (8, 1, 2, 0.2), (16, 0, 100, 0.5), (16, 1, 100, 0.5)]
    settings.append((32, 0, None, None))
    for number, (k, seed, downscale, weight) in enumerate(settings):
        extra = {"relay.k": k, "scene.loader.downscale": downscale, "train.ssim_weight": weight}
        _job(tmp_path, number, "k8", 25.0 + number, 10.0, **UNLABELLED, seed=seed, **extra)
    files = report.write_reports(tmp_path)
    parameters = "relay.k | scene.loader.downscale | train.ssim_weight"
    assert files.table.splitlines()[2].startswith(f"| Variant | seed | {parameters} | PSNR")
    assert _row(files.table, "k8", "1", "16")[3:6] == ["100", "0.5", "28.00"]
    assert _row(files.table, "k8", "0", "32")[3:6] == ["n/a", "n/a", "29.00"]
    mean = pd.read_csv(tmp_path / "summary_mean.csv")
    assert list(mean["relay.k"]) == [8, 16, 32] and list(mean.runs) == [2, 2, 1]
    assert list(mean.psnr_mean) == pytest.approx([25.5, 27.5, 29.0])
    text = files.mean.read_text()
    assert text.splitlines()[2].startswith(f"| Scene | Variant | {parameters} | Runs | PSNR")
    assert _row(text, "juggle", "k8", "16")[3:7] == ["100", "0.5", "2", "27.50 ± 0.71"]
    assert report.main([str(tmp_path)]) == 0  # and says where both of its files are
    listed = capsys.readouterr().out.split("summary of 5 job(s):\n")[1].split()
    assert {str(tmp_path / "summary_mean.md"), str(tmp_path / "summary_mean.csv")} <= set(listed)


def test_repeated_seeds_get_a_mean_and_std_table_in_order_of_first_appearance(tmp_path):
    # k8 appears first (and sorts after k16 as text)
    runs = [("k8", 0, 25.0), ("k16", 0, 26.0), ("k16", 1, 27.0), ("k8", 1, 25.5), ("k16", 2, 28.0)]
    for number, (variant, seed, psnr) in enumerate(runs):
        _job(tmp_path, number, variant, psnr, 10.0 * (seed + 1), seed=seed)
    _job(tmp_path, 9, "k8", None, 5.0, seed=2, status="failed", error="DivergenceError: x")
    files = report.write_reports(tmp_path)
    mean = pd.read_csv(tmp_path / "summary_mean.csv")
    assert list(mean.variant) == ["k8", "k16"]
    assert list(mean.runs) == [2, 3]
    assert list(mean.psnr_mean) == pytest.approx([25.25, 27.0])
    assert list(mean.psnr_std) == pytest.approx([0.5 / 2**0.5, 1.0])  # the sample std
    # Δ per seed against k16 of the same seed, then averaged: (-1.0 - 1.5) / 2
    assert list(mean.delta_psnr_mean) == pytest.approx([-1.25, 0.0])
    text = files.mean.read_text()
    assert _row(text, "juggle", "k16")[2:5] == ["3", "27.00 ± 1.00", "0.00 ± 0.00"]


def test_a_sweep_resumed_in_place_counts_what_its_jobs_built_before_the_interruption(tmp_path):
    # the rerun of each job read everything back (computed 0), but the jobs' folders built it:
    # k8 all 20 s of its lineage, k16 its own 10 s; an older result without the field counts
    # what it computed
    reread = {"train_s_computed": 0.0, "eval_s_total": 2.0, "eval_s_computed": 0.0}
    _job(tmp_path, 0, "k8", 24.0, 20.0, **reread, train_s_built_by_job=20.0, eval_s_built_by_job=2)
    _job(tmp_path, 1, "k16", 23.0, 20.0, **reread, train_s_built_by_job=10.0, eval_s_built_by_job=2)
    _job(tmp_path, 2, "k32", 23.0, 20.0, eval_s_total=2.0, eval_s_computed=2.0)
    text = report.write_reports(tmp_path).markdown.read_text()
    assert _figures(text, "Stage time") == ["40", "60", "0.67", "46", "66", "0.70"]
    assert _row(text, "k8")[1:8] == ["24.00", "+1.00", "n/a", "n/a", "0.8000", "20.0", "20.0"]
    assert _row(text, "k16")[1:8] == ["23.00", "+0.00", "n/a", "n/a", "0.8000", "20.0", "10.0"]
    summary = pd.read_csv(tmp_path / "summary.csv")
    assert summary.train_s_computed.tolist() == [0.0, 0.0, 10.0]  # the CSV keeps the fields
    _job(tmp_path, 3, "k64", 23.0, 20.0, train_s_built_by_job="x")
    with refused(InputError, "train_s_built_by_job", "'x'"):
        report.write_reports(tmp_path)


def test_a_budget_sweep_says_what_a_minute_buys_and_which_points_are_on_the_front(tmp_path):
    runs = [
        ("juggle", "relaygs", 0.5, 23.0, 5),
        ("juggle", "relaygs", 1.0, 24.0, 10),
        ("juggle", "relaygs", 2.0, 24.5, 20),
        ("juggle", "4dgs", 0.5, 22.5, 6),
        ("juggle", "4dgs", 1.0, 23.0, 11),
        ("juggle", "4dgs", 1.0, 24.0, 13),  # a second seed: the point is the mean
        # out of order; multipliers 1 and 2 took the same time (a time cap): no gain from 1 to 2
        ("court", "relaygs", 2.0, 25.0, 10),
        ("court", "relaygs", 0.5, 23.0, 5),
        ("court", "relaygs", 1.0, 24.0, 10),
    ]
    for number, (scene, pipeline, multiplier, psnr, minutes) in enumerate(runs):
        extra = {"scene": scene, "pipeline": pipeline, "budget.multiplier": multiplier}
        _job(tmp_path, number, "k16", psnr, minutes * 60.0, seed=number, **extra)
    files = report.write_reports(tmp_path)
    table = pd.read_csv(tmp_path / "summary_budget.csv")
    assert list(table.pipeline) == ["relaygs"] * 3 + ["4dgs"] * 2 + ["relaygs"] * 3
    assert table.multiplier.tolist()[5:] == [0.5, 1.0, 2.0]
    gains = table.db_per_minute.tolist()
    assert [pd.isna(gain) for gain in gains] == [True, False, False, True, False, True, False, True]
    assert [gains[1], gains[2], gains[4], gains[6]] == pytest.approx([0.2, 0.05, 1.0 / 6.0, 0.2])
    # each scene's front; on court (10 min, 24 dB) is beaten by (10 min, 25 dB)
    assert table.on_front.tolist() == [True, True, True, False, False, True, False, True]
    assert table.runs.tolist() == [1, 1, 1, 1, 2, 1, 1, 1]
    text = files.budget.read_text()
    assert _row(text, "juggle", "relaygs", "0.5")[3:] == ["1", "5.00", "23.00", "n/a", "yes"]
    assert _row(text, "juggle", "relaygs", "1")[3:] == ["1", "10.00", "24.00", "+0.200", "yes"]


def test_a_budget_sweep_whose_jobs_all_failed_gets_its_summary_without_a_budget_table(tmp_path):
    for number, multiplier in enumerate([0.5, 1.0]):
        extra = {"budget.multiplier": multiplier, "status": "failed", "error": "InputError: x"}
        _job(tmp_path, number, "k16", None, 5.0, **extra)
    files = report.write_reports(tmp_path)
    assert files.budget is None and files.pareto is None
    assert "| k16 (failed) | 0.5 | n/a |" in files.markdown.read_text()


NOT_A_NUMBER = "expected a finite number or null"
NOT_FLAT = "expected a number, string, bool or null"  # the tables group and compare values


@pytest.mark.parametrize(
    ("content", "named"),
    [
        (b"\xff\xfe{}", ["utf-8"]),
        (b"{not json", ["unreadable"]),
        (b"{}", ["variant, job, pipeline, scene, seed, psnr"]),
        (b'[{"variant": "k8"}]', ["JSON object"]),
        (b'{"variant": "k8", "pipeline": "relaygs", "scene": "juggle", "seed": 0}', ["job, psnr"]),
        # a value of the wrong type, set in a complete result: named with its key
        ({"job": "x"}, [f"job: {NOT_A_NUMBER}", "'x'"]),
        ({"psnr": "abc"}, [f"psnr: {NOT_A_NUMBER}", "'abc'"]),
        ({"train_s_total": True}, [f"train_s_total: {NOT_A_NUMBER}", "True"]),
        ({"budget.multiplier": "2x"}, [f"budget.multiplier: {NOT_A_NUMBER}", "'2x'"]),
        ({"scene": ["juggle"]}, [f"scene: {NOT_FLAT}", "['juggle']"]),
        ({"variant": {"k": 16}}, [f"variant: {NOT_FLAT}", "{'k': 16}"]),
    ],
)
def test_an_unreadable_incomplete_or_mistyped_result_is_named(sweep, capsys, content, named):
    path = sweep / "1_k16" / "result.json"
    if isinstance(content, dict):
        content = json.dumps({**json.loads(path.read_text()), **content}).encode()
    path.write_bytes(content)
    _refused(capsys, sweep, str(path), *named)
    assert not (sweep / "summary.md").exists()


@pytest.mark.parametrize("name", ["summary.md", "pareto.png"])
def test_a_folder_where_a_report_file_goes_is_named(sweep, capsys, name):
    (sweep / name).mkdir()
    _refused(capsys, sweep, str(sweep / name))


def test_the_mean_table_needs_a_repeated_finished_job_and_an_old_one_goes(tmp_path):
    _job(tmp_path, 0, "k16", 26.0, 20.0, test_set="aaa")
    _job(tmp_path, 1, "k16", 27.0, 20.0, test_set="aaa", seed=1)
    _job(tmp_path, 2, "k16", 28.0, 20.0, seed=2)  # written before results named their test set
    _job(tmp_path, 3, "k16", 25.0, 20.0, test_set="bbb", seed=3)
    text = report.write_reports(tmp_path).mean.read_text()
    assert _row(text, "juggle", "k16", "aaa")[3:5] == ["2", "26.50 ± 0.71"]
    assert _row(text, "juggle", "k16", "n/a")[3:5] == ["1", "28.00"]  # not <NA>
    for number in (0, 1, 2, 3):  # every job failed: nothing to average
        result = tmp_path / f"{number}_k16" / "result.json"
        failed = {**json.loads(result.read_text()), "status": "failed", "psnr": None}
        result.write_text(json.dumps(failed))
    assert report.main([str(tmp_path)]) == 0
    assert not (tmp_path / "summary_mean.md").exists()
    assert not (tmp_path / "summary_mean.csv").exists()
    assert not (tmp_path / "pareto.png").exists()  # nor a plot of the jobs that finished before
    # two copies of one sweep in a folder: the same seed twice is no spread over seeds
    copies = tmp_path / "copies"
    for sweep in ("a", "b"):
        _job(copies / sweep, 0, "k16", 26.0, 20.0)
        _job(copies / sweep, 1, "k8", 25.0, 10.0)
    assert report.write_reports(copies).mean is None
    _job(copies / "c", 0, "k16", 27.0, 20.0, seed=1)
    assert report.write_reports(copies).mean is not None
    mean = pd.read_csv(copies / "summary_mean.csv")
    assert list(mean.seeds) == [2, 1] and list(mean.runs) == [3, 2]


@pytest.mark.parametrize("multiplier", [{}, {"budget.multiplier": 1.0}])
def test_no_budget_table_when_every_job_ran_at_one_multiplier(tmp_path, multiplier):
    for number, psnr in enumerate([25.0, 26.0]):
        _job(tmp_path, number, "k16", psnr, 60.0, **multiplier, seed=number)
    assert report.write_reports(tmp_path).budget is None
    assert not any(tmp_path.glob("summary_budget.*"))


def test_a_pipe_in_a_label_stays_in_its_cell_and_a_delta_near_zero_reads_plus_zero(tmp_path):
    _job(tmp_path, 0, "k16", 26.0, 0.0)
    _job(tmp_path, 1, "k8", 25.996, 0.0)  # Δ -0.004
    path = tmp_path / "1_k8" / "result.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "variant": "k8|fast"}))
    text = report.write_reports(tmp_path).markdown.read_text()
    (row,) = [line for line in text.splitlines() if line.startswith("| k8")]
    assert row.startswith("| k8\\|fast | 26.00 | +0.00 |") and "-0.00" not in row
    assert "Stage time" not in text  # no sharing line without any stage time


@pytest.fixture
def figures(monkeypatch):
    """Every figure the Pareto plot makes, kept to inspect after it is saved."""
    made = []

    class RecordingFigure(pareto.Figure):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(pareto, "Figure", RecordingFigure)
    return made


def test_pareto_labels_of_close_jobs_do_not_overprint_nor_leave_the_plot(tmp_path, figures):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    # four jobs at the top of the plot, two at its bottom, one at its right edge
    times = [5.35, 5.38, 5.40, 5.45, 3.0, 3.02, 8.0]
    scores = [10.03, 10.03, 10.031, 10.032, 9.95, 9.951, 10.03]
    labels = ["no_isolation", "no_gamma", "no_pseudo_views", "k8", "no_stage2", "no_copies", "full"]
    pareto.plot_pareto(times, scores, labels, tmp_path / "p.png", "t")
    (axes,) = figures[0].axes
    renderer = FigureCanvasAgg(figures[0]).get_renderer()
    figures[0].draw_without_rendering()  # lay out at the figure's own dpi again, after saving
    boxes = [Text.get_window_extent(text, renderer) for text in axes.texts]  # text, no leader
    inside = axes.get_window_extent(renderer)
    assert len(boxes) == 7
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    assert all(inside.x0 <= box.x0 and box.x1 <= inside.x1 for box in boxes)
    assert all(inside.y0 <= box.y0 and box.y1 <= inside.y1 for box in boxes)
    # jobs on the same point share one label
    labels = point_labels([1.0, 2.0, 2.0, 1.0], [5.0, 6.0, 6.0, 5.0], ["k64", "k128", "k8", "k64"])
    assert labels == {(1.0, 5.0): "k64", (2.0, 6.0): "k128, k8"}


@pytest.mark.parametrize(("slowest", "scale"), [(30.0, "log"), (15.0, "linear")])
def test_pareto_time_axis_is_logarithmic_only_for_a_wide_time_range(
    tmp_path, figures, slowest, scale
):
    # the slowest job takes 30x (log) or 15x (linear) the fastest; the threshold is 20x
    pareto.plot_pareto([1.0, slowest], [20.0, 25.0], ["a", "b"], tmp_path / "p.png", "t")
    assert figures[0].axes[0].get_xscale() == scale
