"""`python -m relaygs.artifacts [--root DIR] ls | show KEY | eval KEY --scene DIR |
render KEY --scene DIR | ply KEY | verify | gc`: inspect, score, look at, export, check and
clean the artifact store. Exit 0 on success, 1 on a problem (one line on stderr), 2 on usage."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from safetensors import SafetensorError, safe_open

from relaygs.app.evaluation import EVAL_STAGE
from relaygs.cli import OneLineErrorParser, camera_ids, writable_file
from relaygs.data import Scene, load_scene
from relaygs.device import usable_device
from relaygs.errors import RERUN_COMMAND, RelayGSError, resource_error
from relaygs.paths import require_creatable_folder
from relaygs.per_view import PER_VIEW, write_per_view
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.layout import TENSORS_FILE
from relaygs.pipeline.store import (
    VERIFY_HINT,
    ArtifactStore,
    MissingArtifactError,
    StoredArtifact,
)
from relaygs.ply import write_frame_plys
from relaygs.renders import PathSettings, RenderSettings, write_path_render, write_renders
from relaygs.stages import evaluate
from relaygs.stages.scene_model import SceneModel

DEFAULT_ROOT = "outputs/artifacts"
DEFAULT_RENDERS = "outputs/renders"
DEFAULT_PLY = "outputs/ply"
KEY_COLUMN_WIDTH = 16
LINEAGE_COLUMNS = ("psnr", "ssim", "fg_psnr", "num_gaussians", "storage_mb")


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line, run one command, and return the process exit status."""
    args = _parser().parse_args(argv)
    store = ArtifactStore(args.root)
    try:
        if not store.root.is_dir():
            raise RelayGSError(f"no artifact store at {store.root} (pass --root DIR)")
        return args.command_fn(store, args)
    except RelayGSError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except (OSError, MemoryError, RuntimeError) as error:  # out of disk or memory: one line
        failure = resource_error(error, rerun=RERUN_COMMAND)
        if failure is None:
            raise
        print(f"error: {failure}", file=sys.stderr)
        return 1


def _parser() -> argparse.ArgumentParser:
    """The argument parser with one sub-command per store operation."""
    parser = OneLineErrorParser(prog="python -m relaygs.artifacts", description=__doc__)
    parser.add_argument("--root", default=DEFAULT_ROOT, help=f"store root (default {DEFAULT_ROOT})")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("ls", help="list finished artifacts").set_defaults(command_fn=_ls)
    show = commands.add_parser("show", help="print one artifact's manifest and tensors")
    show.add_argument("key", help="full key or a unique prefix (at least 4 hex digits)")
    show.set_defaults(command_fn=_show)
    score = commands.add_parser(
        "eval", help="score one artifact's model on a scene's test views (any stage's output)"
    )
    score.add_argument("key", help="full key or a unique prefix (at least 4 hex digits)")
    _add_scene_arguments(score)
    score.add_argument(
        "--frame-stride", type=int, default=1, metavar="N", help="score every N-th frame"
    )
    outputs = score.add_mutually_exclusive_group()
    outputs.add_argument(
        "--per-view",
        type=writable_file,
        metavar="CSV",
        help="also write each test image's metrics (frame, camera, PSNR, SSIM, fg-PSNR) here",
    )
    outputs.add_argument(
        "--lineage",
        action="store_true",
        help="score every stage's model in its lineage too, one row each (what each stage adds)",
    )
    score.set_defaults(command_fn=_eval)
    render = commands.add_parser(
        "render",
        help="render one artifact's model over time: a PNG per frame and an MP4 per camera",
    )
    render.add_argument("key", help="full key or a unique prefix (at least 4 hex digits)")
    _add_scene_arguments(render)
    render.add_argument(
        "--camera",
        type=int,
        action="append",
        metavar="ID",
        help="camera id to render (repeat for more; default: the test cameras)",
    )
    render.add_argument(
        "--frame-stride", type=int, default=1, metavar="N", help="render every N-th frame"
    )
    render.add_argument(
        "--beside",
        action="append",
        metavar="KEY",
        help="also render this model (trained on the same scene) to the right, e.g. a baseline "
        "or an earlier stage; repeat for more",
    )
    render.add_argument("--truth", action="store_true", help="put the ground truth beside")
    render.add_argument(
        "--error",
        action="store_true",
        help="put the error beside: |render - truth| per pixel, black none, brightest >= 0.25",
    )
    render.add_argument(
        "--path",
        type=int,
        metavar="N",
        help="instead, N views along the orbit that the --camera ids (default: the train "
        "cameras) place around the scene's centre, time running over the frames",
    )
    render.add_argument(
        "--path-frame", type=int, metavar="F", help="with --path: hold the model at frame F"
    )
    render.add_argument("--fps", type=float, default=15.0, help="video frame rate (default 15)")
    render.add_argument("--no-video", action="store_true", help="write PNG frames only")
    render.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (default cpu)")
    render.add_argument(
        "--out", type=Path, help=f"output folder (default {DEFAULT_RENDERS}/<stage>-<key>)"
    )
    render.set_defaults(command_fn=_render)
    ply = commands.add_parser(
        "ply", help="export one artifact's model as 3DGS PLY files, one per frame, for viewers"
    )
    ply.add_argument("key", help="full key or a unique prefix (at least 4 hex digits)")
    ply.add_argument(
        "--frame",
        type=int,
        action="append",
        metavar="F",
        help="frame to export (repeat for more; default: every --frame-stride-th frame)",
    )
    ply.add_argument(
        "--frame-stride", type=int, default=1, metavar="N", help="export every N-th frame"
    )
    ply.add_argument(
        "--out", type=Path, help=f"output folder (default {DEFAULT_PLY}/<stage>-<key>)"
    )
    ply.set_defaults(command_fn=_ply)
    verify = commands.add_parser("verify", help="check every artifact's hashes (exit 1 if bad)")
    verify.set_defaults(command_fn=_verify)
    gc = commands.add_parser("gc", help="remove leftovers of killed builds and stale locks")
    gc.add_argument(
        "--keep",
        nargs="+",
        metavar="KEY",
        help="also remove every artifact that is neither one of these (full keys or unique "
        "prefixes) nor in their lineage (the evaluations of what is kept stay)",
    )
    gc.add_argument("--dry-run", action="store_true", help="only print what would be removed")
    gc.set_defaults(command_fn=_gc)
    return parser


def _add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """`--scene` and the loader options that decide its views as the run loaded them."""
    parser.add_argument(
        "--scene", type=Path, required=True, help="the scene folder it was trained on"
    )
    parser.add_argument(
        "--downscale", type=int, default=1, help="the run's scene.loader.downscale (default 1)"
    )
    parser.add_argument(
        "--test-cameras",
        type=camera_ids,
        metavar="IDS",
        help="the run's scene.loader.test_cameras, e.g. 1,5 (default: the scene's own)",
    )


def _load_scene(args: argparse.Namespace) -> Scene:
    """The `--scene` folder loaded with the run's loader options (`_add_scene_arguments`)."""
    return load_scene(args.scene, downscale=args.downscale, test_cameras=args.test_cameras)


def _ls(store: ArtifactStore, args: argparse.Namespace) -> int:
    """One line per finished artifact: stage, key, size, build seconds, created, upstream."""
    items = store.list()
    print(f"{'STAGE':<12} {'KEY':<{KEY_COLUMN_WIDTH}} {'MB':>9} {'WALL_S':>9}  CREATED  UPSTREAM")
    for item in items:
        manifest = item.manifest
        upstream = ",".join(f"{e.stage}:{e.key[:8]}" for e in manifest.lineage) or "-"
        print(
            f"{item.stage:<12} {item.key[:KEY_COLUMN_WIDTH]:<{KEY_COLUMN_WIDTH}} "
            f"{manifest.size_mb:>9.3f} {manifest.wall_seconds:>9.2f}  "
            f"{manifest.created}  {upstream}"
        )
    print(f"{len(items)} artifact(s) in {store.root}")
    damaged = store.damaged()
    if damaged:
        print(f"{len(damaged)} damaged artifact folder(s) not listed: {VERIFY_HINT}")
    return 0


def _show(store: ArtifactStore, args: argparse.Namespace) -> int:
    """The artifact's folder, manifest (JSON) and tensor names, dtypes and shapes."""
    item = store.find(args.key)
    tensors = _tensor_lines(item)
    print(f"path: {item.path}")
    print(json.dumps(asdict(item.manifest), indent=2, sort_keys=True))
    for line in tensors:
        print(line)
    return 0


def _tensor_lines(item: StoredArtifact) -> list[str]:
    """`tensor <name>: <dtype> <shape>` per stored tensor, read from the file's header; a file
    that cannot be parsed is reported as a damaged artifact, one that a gc removed meanwhile as
    removed."""
    path = item.path / TENSORS_FILE
    try:
        with safe_open(str(path), framework="pt") as tensors:
            views = {name: tensors.get_slice(name) for name in sorted(tensors.keys())}
            return [
                f"tensor {name}: {view.get_dtype()} {list(view.get_shape())}"
                for name, view in views.items()
            ]
    except (OSError, SafetensorError) as error:
        if not item.path.is_dir():  # a gc beside this command removed it after it was found
            name = f"{item.stage}/{item.key[:KEY_COLUMN_WIDTH]}"
            raise MissingArtifactError(f"artifact {name} was removed while it was read") from error
        message = f"damaged artifact: {path} is unreadable ({error}); {VERIFY_HINT}"
        raise RelayGSError(message) from error


def _eval(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Render the artifact's model (with `--lineage`, each model of its lineage too) at the
    scene's test views and print the test metrics, e.g. to see what each stage contributes."""
    _require_stride(args.frame_stride)
    item, artifact = _model_artifact(store, args.key)
    scene = _load_scene(args)
    settings = {"eval": {"frame_stride": args.frame_stride}}
    tests = ", ".join(str(camera.camera_id) for camera in scene.test_cameras) or "none"
    where = f"on {args.scene} (test cameras {tests})"
    if args.lineage:
        entries = _lineage(store, item)
        print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]} and its lineage {where}")
        rows = [
            _scores(entry, store.load(entry.stage, entry.key), scene, settings) for entry in entries
        ]
        print(_lineage_table(entries, rows))
        _note_other_scene(entries, scene)
        return 0
    metrics = _scores(item, artifact, scene, settings)
    print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]} {where}")
    for name, value in metrics.items():
        if isinstance(value, float):
            print(f"  {name:<16}{value:.4f}")
        elif isinstance(value, int) or value is None:
            print(f"  {name:<16}{'n/a' if value is None else value}")
    if args.per_view is not None:
        written = write_per_view(args.per_view, metrics[PER_VIEW])
        print(f"  per-view metrics of {len(metrics[PER_VIEW])} image(s) in {written}")
    _note_other_scene([item], scene)
    return 0


def _scores(
    item: StoredArtifact, artifact: Artifact, scene: Scene, settings: dict
) -> dict[str, Any]:
    """The evaluator's metrics of one stored model, with its storage as result.json has it."""
    metrics = evaluate(scene, artifact, settings)
    metrics["storage_mb"] = item.manifest.size_mb
    return metrics


def _lineage(store: ArtifactStore, item: StoredArtifact) -> list[StoredArtifact]:
    """`item` and every artifact upstream of it, each once, upstream ones first."""
    ordered: dict[str, StoredArtifact] = {}

    def visit(entry: StoredArtifact) -> None:
        for parent in entry.manifest.lineage:
            if parent.key in ordered:
                continue
            if not store.has(parent.stage, parent.key):
                raise MissingArtifactError(
                    f"the lineage of {entry.stage} {entry.key[:KEY_COLUMN_WIDTH]} needs "
                    f"{parent.stage} {parent.key[:KEY_COLUMN_WIDTH]}, which is no longer in "
                    f"{store.root}: score the artifacts still there one by one"
                )
            manifest = store.manifest(parent.stage, parent.key)
            visit(StoredArtifact(store.path(parent.stage, parent.key), manifest))
        ordered[entry.key] = entry

    visit(item)
    return list(ordered.values())


def _lineage_table(entries: list[StoredArtifact], rows: list[dict[str, Any]]) -> str:
    """One line per artifact: stage, key prefix and its LINEAGE_COLUMNS (n/a where missing)."""
    header = ["stage", "key", *LINEAGE_COLUMNS]
    cells = [
        [
            entry.stage,
            entry.key[:KEY_COLUMN_WIDTH],
            *(_cell(row.get(name)) for name in LINEAGE_COLUMNS),
        ]
        for entry, row in zip(entries, rows, strict=True)
    ]
    widths = [max(len(line[column]) for line in [header, *cells]) for column in range(len(header))]
    return "\n".join(
        "  "
        + "  ".join(text.ljust(width) for text, width in zip(line, widths, strict=True)).rstrip()
        for line in [header, *cells]
    )


def _cell(value: Any) -> str:
    """A metric as `eval` prints it: floats to 4 decimals, None as n/a."""
    if value is None:
        return "n/a"
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def _render(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Write the artifact's renders of the chosen cameras over time, or along a camera path,
    and say where they are."""
    settings = _render_settings(args)
    device = usable_device(args.device, "--device")
    item, artifact = _model_artifact(store, args.key)
    others = [_model_artifact(store, key) for key in args.beside or []]
    out = _output_folder(args.out, DEFAULT_RENDERS, item)
    scene = _load_scene(args)
    model = SceneModel.from_artifact(artifact).to(device)
    beside = [SceneModel.from_artifact(other).to(device) for _, other in others]
    if isinstance(settings, PathSettings):
        written = [write_path_render(scene, model, out, settings, beside=beside)]
    else:
        written = write_renders(scene, model, out, settings, beside=beside)
    entries = [item, *(entry for entry, _ in others)]
    names = ", ".join(f"{entry.stage} {entry.key[:KEY_COLUMN_WIDTH]}" for entry in entries)
    print(f"{names} rendered {'side by side ' if others else ''}into {out}")
    for renders in written:
        video = f", video {renders.video}" if renders.video is not None else ""
        what = "path" if renders.camera_id is None else f"camera {renders.camera_id}"
        print(f"  {what}: {len(renders.frames)} frame(s) in {renders.folder}{video}")
    _note_other_scene(entries, scene)
    return 0


def _note_other_scene(items: Sequence[StoredArtifact], scene: Scene) -> None:
    """A stderr note for each model that was not trained on this scene as loaded here (the
    fingerprint in its manifest differs): its test views, and so its scores, may not be the
    run's."""
    for item in items:
        trained_on = item.manifest.provenance.get("scene")
        if trained_on is not None and trained_on != scene.fingerprint:
            print(
                f"note: {item.stage} {item.key[:KEY_COLUMN_WIDTH]} was not trained on "
                f"{scene.root} as loaded here (its files or loader options differ), so its test "
                "views may not be the run's: pass the run's --downscale and --test-cameras "
                "(its max_points and effects also count)",
                file=sys.stderr,
            )


def _render_settings(args: argparse.Namespace) -> RenderSettings | PathSettings:
    """What `render` was asked for: a camera path with `--path`, else the cameras' frames;
    options of the other kind are refused in one line."""
    cameras = tuple(args.camera) if args.camera else None
    fps = None if args.no_video else args.fps
    if args.path is None:
        if args.path_frame is not None:
            raise RelayGSError("--path-frame needs --path N (a camera path of N views)")
        return RenderSettings(cameras, args.frame_stride, args.truth, fps, args.error)
    for flag, given in (("--truth", args.truth), ("--error", args.error)):
        if given:
            raise RelayGSError(f"{flag}: a camera path (--path) has no ground truth to show")
    if args.frame_stride != 1:
        raise RelayGSError("--frame-stride: a camera path (--path) has N views, not frames")
    return PathSettings(args.path, cameras, args.path_frame, fps)


def _ply(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Write the artifact's model at the chosen frames as PLY files and say where they are."""
    _require_stride(args.frame_stride)
    if args.frame and args.frame_stride != 1:
        raise RelayGSError("--frame-stride: --frame names the frames to export; give one of them")
    item, artifact = _model_artifact(store, args.key)
    out = _output_folder(args.out, DEFAULT_PLY, item)
    model = SceneModel.from_artifact(artifact)
    frames = args.frame or range(0, model.num_frames, args.frame_stride)
    written = write_frame_plys(model, out, list(dict.fromkeys(frames)))
    print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]}: {len(written)} PLY file(s) in {out}")
    return 0


def _require_stride(stride: int) -> None:
    """One line unless `--frame-stride` is at least 1."""
    if stride < 1:
        raise RelayGSError(f"--frame-stride must be >= 1, got {stride}")


def _output_folder(given: Path | None, default_root: str, item: StoredArtifact) -> Path:
    """`--out` as an absolute folder that can be written, by default
    `default_root`/<stage>-<key prefix> under the current directory."""
    name = f"{item.stage}-{item.key[:KEY_COLUMN_WIDTH]}"
    return require_creatable_folder((given or Path(default_root) / name).absolute(), "--out")


def _model_artifact(store: ArtifactStore, key_prefix: str) -> tuple[StoredArtifact, Artifact]:
    """The stored model of `key_prefix`, refusing a stored evaluation (it holds no model)."""
    item = store.find(key_prefix)
    if item.stage == EVAL_STAGE:
        raise RelayGSError(
            f"{item.key[:KEY_COLUMN_WIDTH]} is a stored evaluation, not a model: "
            f"`show {key_prefix}` prints its metrics"
        )
    return item, store.load(item.stage, item.key)


def _verify(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Check all artifacts; print each bad one and exit 1 when there is any."""
    problems = store.verify()
    for problem in problems:
        print(f"CORRUPT {problem.path}: {problem.message}")
    total = len(store.list())
    print(f"{total} readable artifact(s), {len(problems)} problem(s) in {store.root}")
    return 1 if problems else 0


def _gc(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Remove garbage (see ArtifactStore.gc) and print what went."""
    keep = None if args.keep is None else [store.find(prefix).key for prefix in args.keep]
    report = store.gc(keep=keep, dry_run=args.dry_run, annotations=(EVAL_STAGE,))
    verb = "would remove" if args.dry_run else "removed"
    for path in report.removed:
        print(f"{verb} {path}")
    for path in report.busy:
        print(f"in use, kept {path}")
    print(f"{verb} {len(report.removed)} path(s), {len(report.busy)} in use")
    return 0
