"""A job's TensorBoard HParams entry, typed so that the dashboard shows what a sweep asks at a
glance: swept keys are marked `differs` (listed first), metrics lead in METRICS order, and every
job of a sweep writes the same experiment, so the dashboard reads alike whichever it picks."""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from typing import Any

from tensorboard.compat.proto.summary_pb2 import Summary
from tensorboard.plugins.hparams import api_pb2, metadata, plugin_data_pb2

from relaygs.app.sweep_axes import SweepAxes

HParamValue = bool | int | float | str
EXCLUDED_SECTIONS = ("paths", "artifacts")  # where files go, not what was run
EXCLUDED_KEYS = ("pipeline.description", "pipeline.nodes.")  # differ between pipelines
IDENTITY_KEYS = ("pipeline.name", "variant")  # held besides the swept keys
METRIC_GROUP = "result"  # each metric is the scalar `result/<name>` of the job's run
METRICS = (  # the declared metrics and their column titles, in the dashboard's order
    ("psnr", "PSNR (dB)"),
    ("fg_psnr", "fg-PSNR (dB)"),
    ("train_s_total", "train time (s)"),
    ("storage_mb", "storage (MB)"),
    ("ssim", "SSIM"),
    ("train_s_computed", "train time computed (s)"),
    ("render_fps", "render FPS"),
    ("num_gaussians", "Gaussians"),
)


def job_hparams(config: Mapping[str, Any], axes: SweepAxes, mode: str) -> dict[str, HParamValue]:
    """The swept keys with this job's values, then IDENTITY_KEYS (`mode` "swept") or every
    setting (`mode` "all") by dotted key; a swept group is not repeated as `<group>.name`."""
    hparams = {key: hparam_value(value) for key, value in axes.values.items()}
    flat = flatten_config({k: v for k, v in config.items() if k not in EXCLUDED_SECTIONS})
    flat = {key: value for key, value in flat.items() if not key.startswith(EXCLUDED_KEYS)}
    chosen = flat if mode == "all" else {key: flat[key] for key in IDENTITY_KEYS if key in flat}
    for key, value in chosen.items():
        group = key.removesuffix(".name")
        if group == key or group not in axes.values:
            hparams.setdefault(key, value)
    return hparams


def metric_tag(name: str) -> str:
    """The scalar tag a metric is logged under."""
    return f"{METRIC_GROUP}/{name}"


def experiment_summary(hparams: Mapping[str, HParamValue], axes: SweepAxes) -> Summary:
    """The experiment: every hparam with its type and domain, and every metric of METRICS."""
    infos = [_hparam_info(name, value, axes.domains.get(name)) for name, value in hparams.items()]
    metrics = [
        api_pb2.MetricInfo(name=api_pb2.MetricName(tag=metric_tag(name)), display_name=title)
        for name, title in METRICS
    ]
    experiment = api_pb2.Experiment(
        hparam_infos=infos, metric_infos=metrics, time_created_secs=time.time()
    )
    return _summary(metadata.EXPERIMENT_TAG, experiment=experiment)


def session_start_summary(
    hparams: Mapping[str, HParamValue], axes: SweepAxes, group: str
) -> Summary:
    """This job's values (typed as `experiment_summary` declares them), as trial `group`."""
    start = plugin_data_pb2.SessionStartInfo(group_name=group, start_time_secs=time.time())
    for name, value in hparams.items():
        domain = axes.domains.get(name)
        typed = _typed(value, _domain_type(domain)) if domain else value
        field = {bool: "bool_value", str: "string_value"}.get(type(typed), "number_value")
        setattr(start.hparams[name], field, typed)
    return _summary(metadata.SESSION_START_INFO_TAG, session_start_info=start)


def session_end_summary() -> Summary:
    """The job ended well (a failed job writes no HParams entry)."""
    end = plugin_data_pb2.SessionEndInfo(status=api_pb2.STATUS_SUCCESS, end_time_secs=time.time())
    return _summary(metadata.SESSION_END_INFO_TAG, session_end_info=end)


def flatten_config(config: Mapping[str, Any], prefix: str = "") -> dict[str, HParamValue]:
    """Nested config as {dotted key: value}; None → "None", lists → their JSON text."""
    flat: dict[str, HParamValue] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_config(value, f"{name}."))
        else:
            flat[name] = hparam_value(value)
    return flat


def hparam_value(value: Any) -> HParamValue:
    """A value TensorBoard's HParams accepts: None → "None", containers → JSON text."""
    if value is None:
        return "None"
    if isinstance(value, bool | int | float | str):
        return value
    return json.dumps(value, sort_keys=True, default=str)


def _hparam_info(name: str, value: HParamValue, domain: list[Any] | None) -> api_pb2.HParamInfo:
    if domain:
        kind = _domain_type(domain)
        info = api_pb2.HParamInfo(name=name, type=kind, differs=len(domain) > 1)
        info.domain_discrete.extend([_typed(v, kind) for v in domain])
        return info
    if isinstance(value, bool):
        info = api_pb2.HParamInfo(name=name, type=api_pb2.DATA_TYPE_BOOL)
        info.domain_discrete.extend([False, True])
        return info
    kind = api_pb2.DATA_TYPE_STRING if isinstance(value, str) else api_pb2.DATA_TYPE_FLOAT64
    return api_pb2.HParamInfo(name=name, type=kind)


def _domain_type(domain: list[Any]) -> int:
    """BOOL when every value is a bool, FLOAT64 when every one is a number, else STRING."""
    values = [hparam_value(v) for v in domain]
    if all(isinstance(v, bool) for v in values):
        return api_pb2.DATA_TYPE_BOOL
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return api_pb2.DATA_TYPE_FLOAT64
    return api_pb2.DATA_TYPE_STRING


def _typed(value: Any, kind: int) -> HParamValue:
    """`value` as an hparam of type `kind` (a STRING one as its text: `true`, `8`)."""
    value = hparam_value(value)
    if kind != api_pb2.DATA_TYPE_STRING or isinstance(value, str):
        return value
    return json.dumps(value)


def _summary(tag: str, **fields: Any) -> Summary:
    data = plugin_data_pb2.HParamsPluginData(**fields)
    summary = Summary()
    summary.value.add(
        tag=tag, metadata=metadata.create_summary_metadata(data), tensor=metadata.NULL_TENSOR
    )
    return summary
