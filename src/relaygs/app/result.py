"""The job's `result.json`: one flat object per run (metrics, costs, identity, and every
parameter the command line or sweep set, by dotted key) that the sweep tables are built from."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from relaygs.app.evaluation import Evaluation
from relaygs.app.plan import RunPlan
from relaygs.pipeline import PipelineRun
from relaygs.pipeline.fsio import publish_text

RESULT_FILE = "result.json"
METRIC_FIELDS = ("psnr", "psnr_cf", "ssim", "fg_psnr", "render_fps", "num_gaussians")
ALWAYS_RECORDED = (  # the ablation axes, whether or not a job set them
    "relay.k",
    "relay.pseudo_views",
    "deform.gamma",
    "deform.isolate_fg_bg",
    "budget.name",
    "budget.multiplier",
)

NOT_RECORDED = ("hydra", "paths.", "artifacts.")  # where outputs go or how Hydra runs

Scalar = bool | int | float | str | None
NO_TEST_VIEWS = (  # why the metrics read n/a when the scene has nothing to evaluate on
    "no test views were scored: the scene holds no test cameras "
    "(hold some out with scene.loader.test_cameras=[ID,...])"
)

STATUS_OK = "ok"
STATUS_FAILED = "failed"  # the run raised: its `error` says how


def build_result(
    cfg: Mapping[str, Any],
    plan: RunPlan,
    run: PipelineRun,
    evaluation: Evaluation,
    storage_mb: float,
    overrides: Sequence[str],
    job: int | None,
    builder: str,
) -> dict[str, Scalar]:
    """The flat result of one run; `*_built_by_job` count what job `builder` (a `BUILT_BY`
    value) built, before an interruption too."""
    metrics = evaluation.metrics
    result = _identity(plan, job)
    result["status"] = STATUS_OK
    result.update({name: _scalar(metrics.get(name)) for name in METRIC_FIELDS})
    result.update(
        {
            "train_s_total": run.train_seconds_total,
            "train_s_computed": run.train_seconds_computed,
            "eval_s_total": evaluation.wall_seconds,
            "eval_s_computed": evaluation.seconds_computed,
            "train_s_built_by_job": run.train_seconds_built_by(builder),
            "eval_s_built_by_job": evaluation.seconds_built_by(builder),
            "storage_mb": storage_mb,
            "cache_hits": sum(report.cache_hit for report in run.reports),
            "stages": len(run.reports),
            "output_key": run.reports[-1].key,
        }
    )
    extra = {name: _scalar(value) for name, value in metrics.items() if name not in result}
    result.update({name: value for name, value in extra.items() if value is not None})
    parameters = recorded_parameters(cfg, plan, overrides)
    return result | {key: value for key, value in parameters.items() if key not in result}


def build_failed_result(
    cfg: Mapping[str, Any],
    plan: RunPlan,
    error: BaseException,
    overrides: Sequence[str],
    job: int | None,
) -> dict[str, Scalar]:
    """The result of a run that raised `error`: status `failed`, its `error_line`, no metrics."""
    result = _identity(plan, job)
    result.update({"status": STATUS_FAILED, "error": error_line(error)})
    result.update({name: None for name in METRIC_FIELDS})
    parameters = recorded_parameters(cfg, plan, overrides)
    return result | {key: value for key, value in parameters.items() if key not in result}


def error_line(error: BaseException) -> str:
    """`<ExceptionType>: <first line of its message>`."""
    message = str(error).strip().splitlines()
    return f"{type(error).__name__}: {message[0]}" if message else type(error).__name__


def recorded_overrides(overrides: Sequence[str]) -> dict[str, str]:
    """{dotted key or group: value text} of the overrides, but where things go and Hydra's."""
    recorded = {}
    for override in overrides:
        key, _, text = override.partition("=")
        key = key.lstrip("+~")
        if key and not key.startswith(NOT_RECORDED):
            recorded[key] = text
    return recorded


def effective_value(cfg: Mapping[str, Any], plan: RunPlan, key: str) -> Scalar:
    """What `key` was for this run: a stage setting as the pipeline set it, before its canonical
    form (None when no node runs that stage), else the config value."""
    head, _, rest = key.partition(".")
    if head in plan.stage_types:
        sections = [config[head] for config in plan.node_configs.values() if head in config]
        return _parameter(_lookup(sections[0], rest)) if sections else None
    return _parameter(_lookup(cfg, key))


def write_result(run_dir: Path, result: Mapping[str, Scalar]) -> Path:
    """Write `result.json` into the run dir, whole or not at all, and return its path."""
    path = Path(run_dir) / RESULT_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    publish_text(path, json.dumps(dict(result), indent=2, allow_nan=False) + "\n")
    return path


def format_summary(result: Mapping[str, Scalar]) -> str:
    """A short human-readable table of one run's results (and why no test view was scored)."""
    rows = [
        ("PSNR", _fmt(result.get("psnr"), ".2f", " dB")),
        ("  colour-fitted", _fmt(result.get("psnr_cf"), ".2f", " dB")),
        ("SSIM", _fmt(result.get("ssim"), ".4f")),
        ("fg-PSNR", _fmt(result.get("fg_psnr"), ".2f", " dB")),
        ("train time", _fmt(result.get("train_s_total"), ".1f", " s")),
        ("  not reused", _fmt(result.get("train_s_computed"), ".1f", " s")),
        ("storage", _fmt(result.get("storage_mb"), ".2f", " MB")),
        ("render FPS", _fmt(result.get("render_fps"), ".1f")),
        ("Gaussians", _fmt(result.get("num_gaussians"), ",.0f")),
        ("cached stages", f"{result.get('cache_hits')} of {result.get('stages')}"),
    ]
    title = f"{_run_label(result)} on {result.get('scene')} (seed {result.get('seed')})"
    width = max(len(label) for label, _ in rows)
    lines = [title, *(f"  {label:<{width}}  {value}" for label, value in rows)]
    if result.get("num_test_images") == 0:
        lines.append(f"  {NO_TEST_VIEWS}")
    return "\n".join(lines)


def _run_label(result: Mapping[str, Scalar]) -> str:
    variant, pipeline = result.get("variant"), result.get("pipeline")
    if variant is None or variant == pipeline:
        return str(pipeline)
    return f"{variant} ({pipeline})"


def _identity(plan: RunPlan, job: int | None) -> dict[str, Scalar]:
    return {
        "experiment": plan.run.experiment_name,
        "variant": plan.run.variant,
        "reference_variant": plan.reference,
        "job": job,
        "pipeline": plan.pipeline.name,
        "scene": plan.scene.name,
        "seed": plan.run.seed,
    }


def recorded_parameters(
    cfg: Mapping[str, Any], plan: RunPlan, overrides: Sequence[str]
) -> dict[str, Scalar]:
    """The ablation axes and every recorded override (a group only without its `.name`)."""
    parameters = {key: effective_value(cfg, plan, key) for key in ALWAYS_RECORDED}
    for key, text in recorded_overrides(overrides).items():
        if f"{key}.name" in parameters or key in parameters:
            continue
        in_config = key.split(".")[0] in cfg  # `+component=x` selects a group, not a key
        parameters[key] = effective_value(cfg, plan, key) if in_config else text
    return parameters


def _lookup(config: Mapping[str, Any], dotted: str) -> Any:
    value: Any = config
    for part in dotted.split(".") if dotted else []:
        if not isinstance(value, Mapping) or part not in value:
            return None
        value = value[part]
    return value


def _parameter(value: Any) -> Scalar:
    """A setting as a result field: a group by its `name`, a list as JSON text, else a scalar."""
    if isinstance(value, Mapping):
        return _scalar(value.get("name"))
    if isinstance(value, list | tuple):
        return json.dumps(value)
    return _scalar(value)


def _scalar(value: Any) -> Scalar:
    """A JSON scalar: non-finite floats and non-scalars become None, tensors their item."""
    if hasattr(value, "item") and callable(value.item):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value if isinstance(value, bool | int | float | str) else None


def _fmt(value: Scalar, spec: str, unit: str = "") -> str:
    return "n/a" if not isinstance(value, int | float) else f"{value:{spec}}{unit}"
