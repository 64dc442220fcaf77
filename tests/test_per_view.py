"""Per-view metrics: per_view.csv and the eval artifact's tensors written and read back,
per-frame means, and the sweep's PSNR-by-frame plot averaged over seeds."""

from types import SimpleNamespace

import pytest

from refusals import refused
from relaygs.app import frame_curves as frame_curves_module
from relaygs.app.evaluation import evaluate_through_store
from relaygs.app.frame_curves import frame_curves
from relaygs.app.summary import collect_results
from relaygs.commands import report
from relaygs.errors import InputError
from relaygs.per_view import (
    PER_VIEW,
    PER_VIEW_FILE,
    frame_means,
    from_tensors,
    read_per_view,
    to_tensors,
    write_per_view,
)
from relaygs.pipeline import ArtifactStore
from sweep_jobs import PNG_SIGNATURE, write_job

RECORDS = [
    {"frame": 0, "camera": 3, "psnr": 25.125, "ssim": 0.75, "fg_psnr": 18.5},
    {"frame": 0, "camera": 9, "psnr": 23.0, "ssim": 0.5, "fg_psnr": None},
    {"frame": 4, "camera": 3, "psnr": 1 / 3, "ssim": 0.25, "fg_psnr": 11.0},
]


@pytest.mark.parametrize("records", [RECORDS, []])
def test_records_survive_the_csv_and_the_artifact_tensors_exactly(tmp_path, records):
    path = write_per_view(tmp_path / "run" / PER_VIEW_FILE, records)
    assert path.read_text().splitlines()[0] == "frame,camera,psnr,ssim,fg_psnr"
    assert read_per_view(path) == records  # 1/3 included: floats round-trip exactly
    tensors = to_tensors(iter(records))  # a generator's records are stored whole
    assert all(bool(t.isfinite().all()) for t in tensors.values() if t.is_floating_point())
    assert from_tensors(tensors) == records
    assert from_tensors({}) is None  # an artifact without per-view records
    # stored columns of unequal length are refused
    tensors = to_tensors(RECORDS)
    tensors["per_view.ssim"] = tensors["per_view.ssim"][:2]
    with refused(InputError, "per_view"):
        from_tensors(tensors)
    del tensors["per_view.ssim"]
    with refused(InputError, "per_view"):
        from_tensors(tensors)


@pytest.mark.parametrize(
    ("content", "named"),
    [
        ("frame,camera,psnr\n0,1,2\n", ["frame,camera,psnr,ssim,fg_psnr"]),
        ("", ["frame,camera,psnr,ssim,fg_psnr"]),
        ("frame,camera,psnr,ssim,fg_psnr\n0,1,2,3\n", [":2:", "5", "4"]),
        ("frame,camera,psnr,ssim,fg_psnr\n0,1,x,3,\n", [":2:", "0,1,x,3,"]),
        ("frame,camera,psnr,ssim,fg_psnr\n0,1,2,3,\n0,1,nan,3,\n", [":3:", "finite"]),
        ("frame,camera,psnr,ssim,fg_psnr\n0.5,1,2,3,\n", [":2:", "0.5"]),
    ],
)
def test_a_damaged_file_is_named_with_its_line(tmp_path, content, named):
    path = tmp_path / PER_VIEW_FILE
    path.write_text(content)
    with refused(InputError, str(path), *named):
        read_per_view(path)


def _job(sweep, number, variant, seed, per_frame, **extra):
    """A job (`write_job`) with a per_view.csv of two cameras per frame whose mean PSNR at frame
    f is per_frame[f]."""
    folder = write_job(sweep, number, variant, 20.0, 10.0 + number, seed=seed, **extra)
    if per_frame is not None:
        records = [
            {"frame": f, "camera": c, "psnr": v + d, "ssim": 0.5, "fg_psnr": v - 5}
            for f, v in per_frame.items()
            for c, d in ((0, 1.0), (1, -1.0))
        ]
        write_per_view(folder / PER_VIEW_FILE, records)


def test_curves_average_the_jobs_of_each_line_where_they_have_values(tmp_path):
    _job(tmp_path, 0, "k8", 0, {0: 20.0, 2: 22.0})
    _job(tmp_path, 1, "k8", 1, {0: 24.0})  # another seed, evaluated at other frames
    _job(tmp_path, 2, "k16", 0, {0: 30.0}, status="failed")
    _job(tmp_path, 3, "k32", 0, None)  # written before per-view metrics existed
    # jobs of one variant on other scenes or settings get lines of their own
    _job(tmp_path, 4, "relaygs", 0, {0: 20.0}, **{"relay.k": 8})
    _job(tmp_path, 5, "relaygs", 0, {0: 26.0}, scene="court", **{"relay.k": 8})
    _job(tmp_path, 6, "relaygs", 0, {0: 22.0}, **{"relay.k": 16})
    _job(tmp_path, 7, "relaygs", 1, {0: 24.0}, **{"relay.k": 16})
    _job(tmp_path, 8, "4dgs", 0, {0: 18.0}, **{"relay.k": None})
    curves = frame_curves(collect_results(tmp_path))
    assert curves["psnr"] == {
        "k8": {0: 22.0, 2: 22.0},
        "relaygs (scene=juggle, relay.k=8)": {0: 20.0},
        "relaygs (scene=court, relay.k=8)": {0: 26.0},
        "relaygs (scene=juggle, relay.k=16)": {0: 23.0},
        "4dgs": {0: 18.0},
    }
    assert curves["fg_psnr"]["k8"] == {0: 17.0, 2: 17.0}  # fg-PSNR 5 dB below the PSNR
    # a frame's mean is over its views that have the metric
    assert frame_means(RECORDS, "psnr") == pytest.approx({0: 24.0625, 4: 1 / 3})
    assert frame_means(RECORDS, "fg_psnr") == {0: 18.5, 4: 11.0}  # the None is left out
    assert list(frame_means(list(reversed(RECORDS)), "psnr")) == [0, 4]  # frames in order
    assert frame_means([{**r, "fg_psnr": None} for r in RECORDS], "fg_psnr") == {}


def test_every_panel_draws_a_line_in_the_colour_the_legend_gives_it(tmp_path, monkeypatch):
    _job(tmp_path, 0, "k8", 0, {0: 20.0, 1: 21.0})
    _job(tmp_path, 1, "k16", 0, {0: 22.0, 1: 23.0})
    curves = frame_curves(collect_results(tmp_path))
    del curves["fg_psnr"]["k8"]  # k8 without fg-PSNR: k16 is the fg panel's first line
    figures = []
    monkeypatch.setattr(frame_curves_module, "save_png", lambda figure, _: figures.append(figure))
    frame_curves_module.plot_frame_curves(curves, tmp_path / "plot.png", "t")
    psnr_axes, fg_axes = figures[0].axes
    colour = {line.get_label(): line.get_color() for line in psnr_axes.lines}
    assert colour["k8"] != colour["k16"]
    assert {line.get_label(): line.get_color() for line in fg_axes.lines} == {"k16": colour["k16"]}
    assert [t.get_text() for t in fg_axes.get_legend().get_texts()] == ["k16"]


def test_the_report_plots_psnr_by_frame_where_a_job_has_per_view_metrics(tmp_path, capsys):
    _job(tmp_path, 0, "k8", 0, None)
    assert report.write_reports(tmp_path).frames is None
    assert not (tmp_path / report.FRAMES_PNG).exists()
    _job(tmp_path, 1, "k8", 1, {0: 20.0, 2: 22.0})
    assert report.main([str(tmp_path)]) == 0
    plot = tmp_path / report.FRAMES_PNG
    assert plot.read_bytes().startswith(PNG_SIGNATURE)
    assert str(plot) in capsys.readouterr().out
    # a damaged file fails the report in one line before it writes anything
    before = (tmp_path / report.SUMMARY_MD).read_text()
    _job(tmp_path, 2, "k16", 0, {0: 21.0})
    (tmp_path / "2_k16" / PER_VIEW_FILE).write_text("frame,camera,psnr,ssim,fg_psnr\n0,0,x,1,\n")
    assert report.main([str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and f"2_k16/{PER_VIEW_FILE}:2" in err
    assert (tmp_path / report.SUMMARY_MD).read_text() == before  # no half-renewed report


@pytest.mark.parametrize(
    ("record", "named"),
    [
        ({"frame": 0, "camera": 1, "psnr": 20.0, "ssim": 0.5}, ["record 0", "fg_psnr"]),
        ({**RECORDS[0], "frame": 0.0}, ["record 0", "frame"]),
        ({**RECORDS[0], "camera": True}, ["record 0", "camera"]),
        ({**RECORDS[0], "psnr": float("nan")}, ["frame 0, camera 3", "psnr", "nan"]),
        ({**RECORDS[0], "ssim": float("inf")}, ["ssim", "inf"]),
        ({**RECORDS[0], "fg_psnr": "18"}, ["fg_psnr", "'18'"]),
    ],
)
def test_records_an_evaluation_gives_are_checked_before_they_are_stored(tmp_path, record, named):
    for store in (to_tensors, lambda records: write_per_view(tmp_path / "v.csv", records)):
        with refused(InputError, *named):
            store([record])
    assert not (tmp_path / "v.csv").exists()


def test_a_stored_evaluation_keeps_its_records_out_of_the_manifest(tmp_path):
    store = ArtifactStore(tmp_path / "store")
    output = SimpleNamespace(node="deform", stage="deform", key="ab" * 32)
    run = SimpleNamespace(reports=[output], output=None)
    scene = SimpleNamespace(fingerprint="scene")
    config = {"eval": {"frame_stride": 1}, "train": {"device": "cpu"}}

    def evaluate(scene, artifact, cfg):
        return {"psnr": 24.0, PER_VIEW: RECORDS}

    first = evaluate_through_store(store, scene, run, config, evaluate)
    again = evaluate_through_store(store, scene, run, config, evaluate)
    assert (first.cache_hit, again.cache_hit) == (False, True)
    assert again.metrics == first.metrics == {"psnr": 24.0, PER_VIEW: RECORDS}
    assert store.manifest("eval", first.key).metrics == {"psnr": 24.0}
