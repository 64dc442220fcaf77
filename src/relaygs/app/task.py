"""One job of `python -m relaygs.run`: validate, prepare the scene, run the stage DAG through
the store, evaluate, log to TensorBoard and write `result.json` (no HydraConfig inside)."""

from __future__ import annotations

import json
import shlex
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import torch
from omegaconf import DictConfig

from relaygs.allocator import keep_freed_memory
from relaygs.app.config import resolve_config
from relaygs.app.evaluation import Evaluation, evaluate_through_store, test_set_id
from relaygs.app.hparams import METRICS, job_hparams
from relaygs.app.plan import RunPlan, plan_run
from relaygs.app.result import (
    RESULT_FILE,
    Scalar,
    build_failed_result,
    build_result,
    format_summary,
    recorded_parameters,
    write_result,
)
from relaygs.app.scenes import prepare_scene, scene_provenance
from relaygs.app.suite import StageSuite, load_stage_suite
from relaygs.app.sweep_axes import SweepAxes
from relaygs.app.tensorboard import TensorBoardLog
from relaygs.data import Scene
from relaygs.data.fingerprint import digest
from relaygs.device import set_threads
from relaygs.errors import resource_error
from relaygs.per_view import METRIC_COLUMNS, PER_VIEW, PER_VIEW_FILE, frame_means, write_per_view
from relaygs.pipeline import (
    BUILT_BY,
    Artifact,
    ArtifactStore,
    NodeReport,
    PipelineRun,
    key_config,
    run_pipeline,
)
from relaygs.pipeline.fsio import file_identity
from relaygs.progress import job_label, print_labelled
from relaygs.shell import python_command, script_command
from relaygs.splat import native, use_backend


class _Outcome(NamedTuple):
    """What a finished job made: its result (without `job_s`) and where its outputs are."""

    result: dict[str, Scalar]
    run: PipelineRun
    log_dir: Path
    scene: Scene
    per_view: Path | None


def run_task(
    cfg: DictConfig | Mapping[str, Any],
    *,
    run_dir: Path,
    original_cwd: Path,
    overrides: Sequence[str] = (),
    job: int | None = None,
    label: str | None = None,
    suite: StageSuite | None = None,
    axes: SweepAxes | None = None,
) -> dict[str, Scalar]:
    """Run one job, write `<run_dir>/result.json` and return it. Bad input raises before
    `run_dir` is touched (bad scene data too, except in a sweep job, where it is that job's
    failure); any other failure is recorded as a `failed` result, then re-raised."""
    started = time.perf_counter()
    config = resolve_config(cfg, original_cwd)
    suite = suite or load_stage_suite()
    plan = plan_run(config, suite.stages, suite.validate, suite.accepted_upstream)
    per_view_file = Path(run_dir) / PER_VIEW_FILE
    per_view_before = file_identity(per_view_file)
    with job_label(label):
        scene = _load_scene(plan) if job is None else None
        try:
            if scene is None:
                scene = _load_scene(plan)
            outcome = _execute(
                config, plan, scene, suite, run_dir, overrides, job, axes or SweepAxes()
            )
            result = outcome.result
            result["job_s"] = time.perf_counter() - started
            result_path = write_result(run_dir, result)
        except Exception as error:
            failure = resource_error(error)
            failed = build_failed_result(config, plan, failure or error, overrides, job)
            failed["job_s"] = time.perf_counter() - started
            if file_identity(per_view_file) != per_view_before:
                per_view_file.unlink(missing_ok=True)  # a failed job writes none
            _record_failure(run_dir, failed)
            if failure is None:
                raise
            raise failure from error
        # flushed before a sweep's next job starts; one block, named by the job side by side
        print_labelled(f"{format_summary(result)}\n{_where(plan, outcome, result_path)}")
    return result


def _load_scene(plan: RunPlan) -> Scene:
    """The run's scene, loaded (generated first, for a synthetic one) with the run's threads;
    a disk or memory failure as a one-line ResourceError."""
    set_threads(plan.run.threads)
    use_backend(plan.splat_backend)
    if plan.splat_backend == "auto" and plan.device == "cpu":
        native.available()  # a first build (or why there is none) is said before any bar
    keep_freed_memory()
    try:
        return prepare_scene(plan.scene, plan.scenes_dir, progress=plan.progress)
    except (OSError, MemoryError, RuntimeError) as error:
        failure = resource_error(error, "scene")
        if failure is None:
            raise
        raise failure from error


def _record_failure(run_dir: Path, failed: dict[str, Scalar]) -> None:
    """Write the failed `result.json`, unless the disk that failed the job refuses it too: the
    error raised next, not this second one, says what went wrong."""
    try:
        write_result(run_dir, failed)
    except OSError as error:
        if resource_error(error) is None:
            raise


def _execute(
    config: dict[str, Any],
    plan: RunPlan,
    scene: Scene,
    suite: StageSuite,
    run_dir: Path,
    overrides: Sequence[str],
    job: int | None,
    axes: SweepAxes,
) -> _Outcome:
    """Run the stages on the scene, evaluate and log (into the run folder itself, so that
    TensorBoard names the run after it: a sweep's job folder `0_k8`)."""
    store = ArtifactStore(plan.artifacts_root)
    # who builds the artifacts: the run folder and a digest of the job, scene and keyed
    # settings, so a job resumed in its folder is told from another job run there later
    nodes = {node.name: key_config(plan.config_for(node)) for node in plan.pipeline.nodes.values()}
    job_digest = digest({"job": job, "scene": scene.fingerprint, "nodes": nodes})[:12]
    builder = {BUILT_BY: f"{Path(run_dir).resolve()}#{job_digest}"}
    _note_earlier_run(Path(run_dir), config, plan, overrides, job)
    log = TensorBoardLog(Path(run_dir))
    suite.add_sink(log)
    try:
        run = run_pipeline(
            plan.pipeline,
            suite.stages,
            scene,
            plan.config_for,
            store,
            schema_versions=suite.schema_versions,
            on_corrupt=plan.on_corrupt,
            on_node_done=_announce,
            canonical=suite.canonical,
            provenance={**scene_provenance(plan.scene), **builder},
        )
        _note_reused_stages(log, suite, run, Path(run_dir))
        evaluation = evaluate_through_store(
            store, scene, run, plan.eval_config, suite.evaluate, plan.on_corrupt, builder
        )
        _announce_evaluation(evaluation)
        per_view = _record_per_view(Path(run_dir), log, evaluation)
        _log_previews(log, suite, scene, run.output, plan.preview_frames)
        storage_mb = run.reports[-1].size_mb  # not read again: a gc may have removed it since
        result = build_result(
            config, plan, run, evaluation, storage_mb, overrides, job, builder[BUILT_BY]
        )
        result["test_set"] = test_set_id(scene, evaluation.metrics)
        notes = [f"[{report.node}] {note}" for report in run.reports for note in report.notes]
        if notes:
            result["notes"] = " ".join(notes)
        metrics = {name: result[name] for name, _ in METRICS}
        log.add_hparams(job_hparams(config, axes, plan.hparams), metrics, axes, Path(run_dir).name)
    finally:
        suite.remove_sink(log)
        log.close()
    return _Outcome(result, run, log.log_dir, scene, per_view)


def _record_per_view(run_dir: Path, log: TensorBoardLog, evaluation: Evaluation) -> Path | None:
    """Write `per_view.csv` and log its per-frame means; None (and no earlier run's file left,
    which the sweep report would take for this run's) when there are no per-view metrics."""
    records = evaluation.metrics.get(PER_VIEW)
    if records is None:
        (run_dir / PER_VIEW_FILE).unlink(missing_ok=True)
        return None
    for metric in METRIC_COLUMNS:
        for frame, value in frame_means(records, metric).items():
            log.add_scalar(f"eval/{metric}_by_frame", value, frame)
    return write_per_view(run_dir / PER_VIEW_FILE, records)


def _note_reused_stages(
    log: TensorBoardLog, suite: StageSuite, run: PipelineRun, run_dir: Path
) -> None:
    """Note each stage read from the store (`reused/<stage>`) instead of replaying its curves,
    whose points would all carry this moment's time."""
    for report in run.reports:
        if report.cache_hit:
            records = suite.logged_scalars(run.artifacts[report.node])
            log.add_text(f"reused/{report.stage}", _reuse_note(report, records, run_dir))


def _reuse_note(report: NodeReport, records: Sequence[tuple[int, dict]], run_dir: Path) -> str:
    """The Markdown note on a stage this job read from the store."""
    builder = report.built_by.partition("#")[0] if report.built_by else None
    if builder is None:
        where = "an earlier run"
    elif Path(builder).parent == run_dir.resolve().parent:
        where = f"run `{Path(builder).name}`"  # a job of the same sweep, named as TensorBoard does
    else:
        where = f"`{builder}`"
    note = (
        f"**{report.stage}** (node `{report.node}`) was read from the artifact store, not "
        f"trained by this job: artifact `{report.key[:16]}`, built in "
        f"{report.wall_seconds:.1f} s by {where}, whose TensorBoard run holds its curves."
    )
    if records:
        step, scalars = records[-1]
        values = ", ".join(f"{name} {value:.4g}" for name, value in scalars.items())
        note += f" Its last logged step, {step}: {values}."
    return note


def _note_earlier_run(
    run_dir: Path,
    config: dict[str, Any],
    plan: RunPlan,
    overrides: Sequence[str],
    job: int | None,
) -> None:
    """Say on stderr when the run folder already holds another run (TensorBoard would merge
    their curves); a job resumed in place is not told to use another folder."""
    events = any(run_dir.glob("events.out.tfevents.*"))
    result = (run_dir / RESULT_FILE).is_file()
    if not result or (job is not None and _is_same_job(run_dir, config, plan, overrides, job)):
        if events and not result:
            print_labelled(
                f"note: {run_dir} holds the TensorBoard curves of a run stopped before its "
                f"{RESULT_FILE}; TensorBoard shows them with this run's",
                sys.stderr,
            )
        return
    if events or result:
        replaced = f"its {RESULT_FILE} is replaced and " if result else ""
        print_labelled(
            f"note: {run_dir} already holds a run: {replaced}TensorBoard shows its curves and "
            "this run's as one run; give each run its own folder (hydra.run.dir, or "
            "hydra.sweep.dir for a sweep)",
            sys.stderr,
        )


def _is_same_job(
    run_dir: Path, config: dict[str, Any], plan: RunPlan, overrides: Sequence[str], job: int
) -> bool:
    """Whether the folder's `result.json` records sweep job `job` with the parameters this job
    records (`recorded_parameters`: its overrides as it would write them)."""
    try:
        earlier = json.loads((run_dir / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(earlier, dict) or earlier.get("job") != job:
        return False
    parameters = recorded_parameters(config, plan, overrides)
    return all(earlier.get(key) == value for key, value in parameters.items())


def _announce(report: NodeReport) -> None:
    """Say whether a node's artifact was reused or built (and what corrupt one it replaced),
    and its notes on stderr, flushed so a log shows each stage as it ends."""
    key, seconds = report.key[:12], report.wall_seconds
    if report.cache_hit:
        line = f"reused {report.stage} artifact {key} from the store "
        line += f"(built earlier in {seconds:.1f} s)"
    else:
        line = f"built {report.stage} artifact {key} in {seconds:.1f} s"
    print_labelled(f"[{report.node}] {line}{_replacing(report.replaced_corrupt)}")
    for note in report.notes:
        print_labelled(f"note: [{report.node}] {note}", sys.stderr)


def _announce_evaluation(evaluation: Evaluation) -> None:
    """Say whether the test metrics were read back from the store or computed now (flushed)."""
    key, seconds = evaluation.key[:12], evaluation.wall_seconds
    if evaluation.cache_hit:
        line = f"reused evaluation {key} from the store (made earlier in {seconds:.1f} s)"
    else:
        line = f"evaluated the test views in {seconds:.1f} s (stored as {key})"
    print_labelled(f"[eval] {line}{_replacing(evaluation.replaced_corrupt)}")


def _replacing(problem: str | None) -> str:
    """The status line's clause for a stored artifact that failed its check, else nothing."""
    return (
        "" if problem is None else f", replacing the stored one, which failed its check: {problem}"
    )


def _log_previews(
    log: TensorBoardLog, suite: StageSuite, scene: Any, model: Artifact, count: int
) -> None:
    """Log the first test camera's render, truth and error at `count` spread frames."""
    first_views = scene.views_at(0, "test")
    if count <= 0 or not first_views:
        return
    count = min(count, scene.num_frames)  # there are no more frames to show
    camera_id = first_views[0].camera.camera_id
    last = scene.num_frames - 1
    frames = sorted({round(i * last / max(count - 1, 1)) for i in range(count)})
    for frame in frames:
        view = next(
            (v for v in scene.views_at(frame, "test") if v.camera.camera_id == camera_id), None
        )
        if view is None:
            continue
        with torch.no_grad():
            render = suite.render_model(model, view.camera, view.time)
        log.add_comparison("eval/render_vs_truth", render, scene.image(view), frame)


def _where(plan: RunPlan, outcome: _Outcome, result_path: Path) -> str:
    """Where this run's outputs are, and shell-quoted commands that export and render its
    model with the run's scene loading, device and threads."""
    output = outcome.run.reports[-1]
    scene = outcome.scene
    loader = f" --downscale {scene.downscale}" if scene.downscale != 1 else ""
    if plan.scene.loader.get("test_cameras") is not None:
        ids = ",".join(str(camera.camera_id) for camera in scene.test_cameras) or "[]"
        loader += f" --test-cameras {shlex.quote(ids)}"
    device = f" --device {shlex.quote(plan.device)}" if plan.device != "cpu" else ""
    threads = f" --threads {plan.run.threads}" if plan.run.threads is not None else ""
    root, scene_dir = shlex.quote(str(plan.artifacts_root)), shlex.quote(str(scene.root))
    artifacts = f"{python_command()} -m relaygs.artifacts --root {root}"
    lines = [
        "outputs:",
        f"  result       {result_path}",
        *([f"  per view     {outcome.per_view}"] if outcome.per_view else []),
        f"  tensorboard  {script_command('tensorboard')} --logdir "
        f"{shlex.quote(str(outcome.log_dir))}",
        f"  model        {output.path}",
        f"  store        {plan.artifacts_root}  ({artifacts} ls)",
        f"  ply          {artifacts} ply {output.key[:16]}{threads}",
        f"  videos       {artifacts} render {output.key[:16]} --scene {scene_dir}{loader} "
        f"--truth --error{device}{threads}",
    ]
    return "\n".join(lines)
