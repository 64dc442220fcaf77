"""`python -m relaygs.artifacts ls|show|eval|render|ply|verify|gc`: inspect, score, render, export,
check and clean the artifact store; exit 1 on a problem (one line on stderr), 2 on usage."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

from safetensors import SafetensorError, safe_open

from relaygs.app.evaluation import EVAL_STAGE
from relaygs.cli import (
    OneLineErrorParser,
    int_at_least,
    one_line_failures,
    path_argument,
    positive_float,
    writable_file,
)
from relaygs.commands.artifact_models import (
    KEY_COLUMN_WIDTH,
    KEY_HELP,
    add_model_arguments,
    key_prefix,
    load_run_scene,
    model_artifact,
    note_other_scene,
)
from relaygs.commands.artifacts_eval import run_eval, run_gap
from relaygs.device import set_threads, usable_device
from relaygs.errors import RelayGSError, UsageError
from relaygs.paths import require_creatable_folder
from relaygs.pipeline.integrity import CorruptArtifactError
from relaygs.pipeline.layout import LOCKS_DIR, TENSORS_FILE
from relaygs.pipeline.store import VERIFY_HINT, ArtifactStore, MissingArtifactError, StoredArtifact
from relaygs.ply import write_frame_plys
from relaygs.renders import PathSettings, RenderSettings, write_path_render, write_renders
from relaygs.train.scene_model import SceneModel

DEFAULT_ROOT = "outputs/artifacts"
RENDERS_FOLDER = "renders"
PLY_FOLDER = "ply"
STORE_FOLDER = "artifacts"  # a run's store: <paths.outputs>/artifacts


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line, run one command, and return the process exit status."""
    args = _parser().parse_args(argv)
    return one_line_failures(lambda: _run(args))


def _run(args: argparse.Namespace) -> int:
    """Run the chosen command on the store; contradicting options exit 2 as argparse's do."""
    store = ArtifactStore(args.root)
    if not store.root.is_dir():
        raise RelayGSError(f"no artifact store at {store.root} (pass --root DIR)")
    try:
        return args.command_fn(store, args)
    except UsageError as error:
        print(f"error: {error} (see {_parser().prog} {args.command} --help)", file=sys.stderr)
        return 2
    except CorruptArtifactError as error:
        raise CorruptArtifactError(f"{error}; {REPAIR_HINT}") from error


REPAIR_HINT = (
    "a run that needs a damaged artifact rebuilds it (artifacts.on_corrupt=rebuild, the "
    "default), or delete its folder"
)


def _parser() -> argparse.ArgumentParser:
    """The argument parser with one sub-command per store operation."""
    parser = OneLineErrorParser(prog="python -m relaygs.artifacts", description=__doc__)
    parser.add_argument(
        "--root",
        type=path_argument,
        default=DEFAULT_ROOT,
        help=f"store root (default {DEFAULT_ROOT})",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("ls", help="list finished artifacts").set_defaults(command_fn=_ls)
    show = commands.add_parser("show", help="print one artifact's manifest and tensors")
    show.add_argument("key", type=key_prefix, help=KEY_HELP)
    show.set_defaults(command_fn=_show)
    score = commands.add_parser(
        "eval", help="score one artifact's model on a scene's test views (any stage's output)"
    )
    add_model_arguments(score, "score", stride_note="; a run scores every eval.frame_stride-th")
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
    score.set_defaults(command_fn=run_eval)
    gap = commands.add_parser(
        "gap",
        help="score a model and its lineage on the train and the test views, foreground and "
        "background apart (the train/test gap per stage)",
    )
    add_model_arguments(gap, "score")
    gap.add_argument(
        "--colour-fit",
        action="store_true",
        help="first map each camera's renders through the per-channel gain and offset that fit "
        "its images best (what is left once a camera's own colour response is allowed for)",
    )
    gap.set_defaults(command_fn=run_gap)
    render = commands.add_parser(
        "render",
        help="render one artifact's model over time: a PNG per frame and an MP4 per camera",
    )
    add_model_arguments(render, "render")
    render.add_argument(
        "--camera",
        type=int,
        action="append",
        metavar="ID",
        help="camera id to render (repeat for more; default: the test cameras)",
    )
    render.add_argument(
        "--beside",
        type=key_prefix,
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
        type=int_at_least(1),
        metavar="N",
        help="instead, N views along the orbit that the --camera ids (default: the train "
        "cameras) place around the scene's centre, time running over the frames",
    )
    render.add_argument(
        "--path-frame", type=int, metavar="F", help="with --path: hold the model at frame F"
    )
    render.add_argument(
        "--fps", type=positive_float, default=15.0, help="video frame rate (default 15)"
    )
    render.add_argument("--no-video", action="store_true", help="write PNG frames only")
    _add_out_argument(render, RENDERS_FOLDER)
    render.set_defaults(command_fn=_render)
    ply = commands.add_parser(
        "ply", help="export one artifact's model as 3DGS PLY files, one per frame, for viewers"
    )
    add_model_arguments(ply, "export", scene=False)
    ply.add_argument(
        "--frame",
        type=int,
        action="append",
        metavar="F",
        help="frame to export (repeat for more; default: every --frame-stride-th frame)",
    )
    _add_out_argument(ply, PLY_FOLDER)
    ply.set_defaults(command_fn=_ply)
    verify = commands.add_parser("verify", help="check every artifact's hashes (exit 1 if bad)")
    verify.set_defaults(command_fn=_verify)
    gc = commands.add_parser("gc", help="remove leftovers of killed builds and stale locks")
    gc.add_argument(
        "--keep",
        type=key_prefix,
        nargs="+",
        metavar="KEY",
        help="also remove every artifact that is neither one of these (full keys or unique "
        "prefixes) nor in their lineage (the evaluations of what is kept stay)",
    )
    gc.add_argument("--dry-run", action="store_true", help="only print what would be removed")
    gc.set_defaults(command_fn=_gc)
    return parser


def _add_out_argument(parser: argparse.ArgumentParser, kind: str) -> None:
    """`--out`, the folder a `kind` export goes to (`_output_folder`)."""
    parser.add_argument(
        "--out",
        type=path_argument,
        help=f"output folder (default <outputs>/{kind}/<stage>-<key>: beside a run's "
        "artifacts folder, else ./outputs)",
    )


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
    """`tensor <name>: <dtype> <shape>` per stored tensor from the file's header; an unparsable
    file is a damaged artifact, one a gc removed meanwhile a removed one."""
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


def _render(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Write the artifact's renders over time or along a camera path; say where they are."""
    settings = _render_settings(args)
    device = usable_device(args.device, "--device")
    set_threads(args.threads)
    item, artifact = model_artifact(store, args.key)
    others = [model_artifact(store, key) for key in args.beside or []]
    out = _output_folder(args.out, RENDERS_FOLDER, item, store)
    scene = load_run_scene(args, item)
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
    note_other_scene(entries, scene)
    return 0


def _render_settings(args: argparse.Namespace) -> RenderSettings | PathSettings:
    """A camera path with `--path`, else the cameras' frames; other-kind options are refused."""
    cameras = tuple(args.camera) if args.camera else None
    fps = None if args.no_video else args.fps
    if args.path is None:
        if args.path_frame is not None:
            raise UsageError("--path-frame needs --path N (a camera path of N views)")
        return RenderSettings(cameras, args.frame_stride, args.truth, fps, args.error)
    for flag, given in (("--truth", args.truth), ("--error", args.error)):
        if given:
            raise UsageError(f"{flag}: a camera path (--path) has no ground truth to show")
    if args.frame_stride != 1:
        raise UsageError("--frame-stride: a camera path (--path) has N views, not frames")
    return PathSettings(args.path, cameras, args.path_frame, fps)


def _ply(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Write the artifact's model at the chosen frames as PLY files and say where they are."""
    if args.frame and args.frame_stride != 1:
        raise UsageError("--frame-stride: --frame names the frames to export; give one of them")
    set_threads(args.threads)
    item, artifact = model_artifact(store, args.key)
    out = _output_folder(args.out, PLY_FOLDER, item, store)
    model = SceneModel.from_artifact(artifact)
    frames = args.frame or range(0, model.num_frames, args.frame_stride)
    written = write_frame_plys(model, out, list(dict.fromkeys(frames)))
    print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]}: {len(written)} PLY file(s) in {out}")
    return 0


def _output_folder(
    given: Path | None, kind: str, item: StoredArtifact, store: ArtifactStore
) -> Path:
    """`--out` as a writable absolute folder, by default <outputs>/`kind`/<stage>-<key>."""
    outputs = store.root.parent if store.root.name == STORE_FOLDER else Path("outputs")
    default = outputs / kind / f"{item.stage}-{item.key[:KEY_COLUMN_WIDTH]}"
    return require_creatable_folder((given or default).absolute(), "--out")


def _verify(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Check all artifacts; print each bad one and exit 1 when there is any."""
    sound, problems = store.verify_all()
    for problem in problems:
        print(f"CORRUPT {problem.path}: {problem.message}")
    total = len(sound) + len(problems)
    print(f"{len(problems)} problem(s) among {total} artifact(s) in {store.root}")
    if problems:
        print(REPAIR_HINT)
    return 1 if problems else 0


def _gc(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Remove garbage (see ArtifactStore.gc) and print what went."""
    keep = None if args.keep is None else [store.find(prefix).key for prefix in args.keep]
    report = store.gc(keep=keep, dry_run=args.dry_run, annotations=(EVAL_STAGE,))
    verb = "would remove" if args.dry_run else "removed"
    folders = [path for path in report.removed if path.parent.name != LOCKS_DIR]
    for path in folders:
        print(f"{verb} {path}")
    for path in report.busy:
        print(f"in use, kept {path}")
    locks = len(report.removed) - len(folders)
    print(
        f"{verb} {len(folders)} folder(s) and {locks} free lock file(s) "
        f"(in {store.root / LOCKS_DIR}), {len(report.busy)} in use"
    )
    return 0
