"""What `tensorboard --logdir SWEEP` shows, read back with TensorBoard's own event reader and
its HParams backend (the code behind the dashboard's table): run names, the swept key first,
every declared metric, tag names, labelled previews and the sweep-level run."""

import json

import cv2
import numpy as np
import pytest
from tensorboard import context
from tensorboard.backend.event_processing.data_provider import MultiplexerDataProvider
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.backend.event_processing.plugin_event_multiplexer import EventMultiplexer
from tensorboard.plugins import base_plugin
from tensorboard.plugins.hparams import (
    api_pb2,
    backend_context,
    get_experiment,
    list_session_groups,
    plugin_data_pb2,
)

from conftest import run_main
from relaygs.app.captions import CAPTION_HEIGHT
from relaygs.app.hparams import METRICS, job_hparams, metric_tag
from relaygs.app.sweep_axes import SweepAxes, recorded_sweep_axes, sweep_axes
from relaygs.app.tensorboard import TensorBoardLog

SCENE = ["scene.frames=6", "scene.width=16", "scene.height=9"]
EVERYTHING = {"images": 0, "scalars": 0, "tensors": 0}


def _hparams_dashboard(logdir):
    """The runs, experiment and session groups TensorBoard's HParams backend gives the web page
    over a log folder, asked as the page asks."""
    multiplexer = EventMultiplexer()
    multiplexer.AddRunsFromDirectory(str(logdir))
    multiplexer.Reload()
    provider = MultiplexerDataProvider(multiplexer, str(logdir))
    tb_context = base_plugin.TBContext(
        logdir=str(logdir), multiplexer=multiplexer, data_provider=provider
    )
    backend, request_context = backend_context.Context(tb_context), context.RequestContext()
    request = api_pb2.GetExperimentRequest(hparams_limit=1000)
    experiment = get_experiment.Handler(request_context, backend, "", request).run()
    request = api_pb2.ListSessionGroupsRequest(start_index=0, slice_size=100)
    request.allowed_statuses.extend([api_pb2.STATUS_SUCCESS])
    for info in experiment.hparam_infos:
        request.col_params.add(hparam=info.name)
    for info in experiment.metric_infos:
        request.col_params.add(metric=info.name)
    groups = list_session_groups.Handler(request_context, backend, "", request).run()
    return sorted(multiplexer.Runs()), experiment, groups.session_groups


def test_the_dashboard_of_a_sweep(fakes, tmp_path):
    # a two-job `ablation_k` sweep (k = 8, 16) on fake stages: HParams name the swept key first
    assert run_main(["+experiment=ablation_k", "relay.k=8,16", "budget=smoke", *SCENE]) == 0
    (sweep,) = tmp_path.glob("outputs/sweeps/*")
    runs, experiment, groups = _hparams_dashboard(sweep)
    assert runs == ["0_k8", "1_k16", "sweep"]  # run names are the job folders
    names = [info.name for info in experiment.hparam_infos]
    assert names == ["relay.k", "pipeline.name", "variant"]
    swept = experiment.hparam_infos[0]
    assert swept.differs and list(swept.domain_discrete) == [8, 16]
    assert not any(info.differs for info in experiment.hparam_infos[1:])
    metrics = [info.name.tag for info in experiment.metric_infos]
    assert metrics == [metric_tag(name) for name, _ in METRICS]  # every one declared
    # the page shows the first five metrics without a click: these lead
    leading = ("psnr", "fg_psnr", "train_s_total", "storage_mb")
    assert metrics[:4] == [metric_tag(name) for name in leading]
    rows = {group.name: group for group in groups}
    assert set(rows) == {"0_k8", "1_k16"}  # the trial ids are the job names too
    for name, k in (("0_k8", 8), ("1_k16", 16)):
        result = json.loads((sweep / name / "result.json").read_text())
        assert rows[name].hparams["relay.k"].number_value == k
        values = {value.name.tag: value.value for value in rows[name].metric_values}
        assert values[metric_tag("psnr")] == pytest.approx(result["psnr"])
        assert values[metric_tag("storage_mb")] == pytest.approx(result["storage_mb"])
        assert values[metric_tag("train_s_total")] == pytest.approx(result["train_s_total"])
    # tags named by group; a stage read back is a note
    first = EventAccumulator(str(sweep / "0_k8"), size_guidance=EVERYTHING)
    first.Reload()
    second = EventAccumulator(str(sweep / "1_k16"), size_guidance=EVERYTHING)
    second.Reload()
    for events in (first, second):
        scalars = set(events.Tags()["scalars"])
        assert {"train/relay/loss", "train/deform/loss", "eval/psnr_by_frame"} <= scalars
        assert not any(tag.startswith(("decouple/", "relay/", "deform/")) for tag in scalars)
        # four frames spread over the six, each a labelled render · truth · error
        previews = events.Images("eval/render_vs_truth")
        assert [image.step for image in previews] == [0, 2, 3, 5]
        assert _has_caption(previews[0].encoded_image_string)
    assert "train/decouple/loss" in first.Tags()["scalars"]  # job 0 trained decouple
    assert "train/decouple/loss" not in second.Tags()["scalars"]  # job 1 read it back
    assert "reused/decouple/text_summary" in second.Tags()["tensors"]
    # the sweep run holds the report's plots and table
    events = EventAccumulator(str(sweep / "sweep"), size_guidance=EVERYTHING)
    events.Reload()
    assert sorted(events.Tags()["images"]) == ["sweep/pareto", "sweep/psnr_by_frame"]
    (table,) = events.Tensors("sweep/summary/text_summary")
    assert table.tensor_proto.string_val[0].decode() == (sweep / "summary.md").read_text()


def _has_caption(png: bytes) -> bool:
    """Whether the image starts with a black band holding white text (a caption)."""
    pixels = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    band = pixels[:CAPTION_HEIGHT]
    return bool((band > 200).any()) and float(np.median(band)) == 0.0


def test_booleans_stay_booleans_and_mixed_axes_become_text(tmp_path):
    axes = SweepAxes({"relay.k": [8, None]}, {"relay.k": None})
    pipeline = {"name": "relaygs", "description": "d", "nodes": {"a": {"stage": "decouple"}}}
    config = {"deform": {"gamma": True}, "variant": "x", "pipeline": pipeline}
    params = job_hparams({**config, "paths": {"outputs": "/x"}}, axes, "all")
    assert params == {
        "relay.k": "None",
        "deform.gamma": True,
        "variant": "x",
        "pipeline.name": "relaygs",
    }
    log = TensorBoardLog(tmp_path)
    log.add_hparams(params, {"psnr": 20.0}, axes, "job")
    log.close()
    events = EventAccumulator(str(tmp_path))
    events.Reload()
    content = events.PluginTagToContent("hparams")
    experiment = plugin_data_pb2.HParamsPluginData.FromString(content["_hparams_/experiment"])
    infos = {info.name: info for info in experiment.experiment.hparam_infos}
    assert infos["deform.gamma"].type == api_pb2.DATA_TYPE_BOOL
    assert list(infos["deform.gamma"].domain_discrete) == [False, True]
    assert infos["relay.k"].type == api_pb2.DATA_TYPE_STRING
    assert list(infos["relay.k"].domain_discrete) == ["8", "None"]
    start = plugin_data_pb2.HParamsPluginData.FromString(
        content["_hparams_/session_start_info"]
    ).session_start_info
    assert start.hparams["deform.gamma"].bool_value is True
    assert start.hparams["relay.k"].string_value == "None"
    assert start.group_name == "job"
    axes = SweepAxes({"pipeline": ["relaygs", "4dgs"]}, {"pipeline": "4dgs"})
    config = {"deform": {"gamma": True}, "variant": "4dgs", "pipeline": {"name": "4dgs"}}
    # without "all": the swept keys and identity; a swept group is not repeated as `.name`
    assert job_hparams(config, axes, "swept") == {"pipeline": "4dgs", "variant": "4dgs"}
    # sweep axes keep each value's type; a single run or unreadable record has none
    jobs = [
        ["+component=full", "deform.gamma=true", "relay.k=8", "seed=0"],
        ["+component=no_gamma", "deform.gamma=false", "relay.k=null", "seed=0"],
    ]
    axes = sweep_axes(jobs, jobs[1])
    assert axes.domains == {
        "component": ["full", "no_gamma"],
        "deform.gamma": [True, False],
        "relay.k": [8, None],
    }
    assert axes.values == {"component": "no_gamma", "deform.gamma": False, "relay.k": None}
    # a single run, or an unreadable record: no axes
    assert recorded_sweep_axes(tmp_path, ["relay.k=8"]) == SweepAxes()
    (tmp_path / "multirun.yaml").write_text("hydra: [")
    assert recorded_sweep_axes(tmp_path, ["relay.k=8"]) == SweepAxes()
