"""What the store's model commands (`artifacts eval`, `render`, `ply`) share: the stored model a
key names, the scene it was trained on loaded as the run loaded it (with a note when it was
not), and the `--device`, `--threads` and `--frame-stride` options."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from relaygs.app.evaluation import EVAL_STAGE
from relaygs.app.plan import MAX_THREADS
from relaygs.app.scenes import recorded_loading
from relaygs.cli import camera_ids, int_at_least, path_argument
from relaygs.data import Scene, load_scene
from relaygs.device import parse_device
from relaygs.errors import InputError, RelayGSError
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.store import ArtifactStore, StoredArtifact

KEY_COLUMN_WIDTH = 16
FLAGGED_LOADING = ("downscale", "test_cameras")
"""The recorded loader options the model commands take on the command line (`--downscale`,
`--test-cameras`); a run's max_points and effects are always taken from its manifest."""


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """`--scene` and the loader options that decide its views as the run loaded them."""
    parser.add_argument(
        "--scene", type=path_argument, required=True, help="the scene folder it was trained on"
    )
    parser.add_argument(
        "--downscale",
        type=int_at_least(1),
        help="the run's scene.loader.downscale (default: the one the model's manifest records, "
        "else 1)",
    )
    parser.add_argument(
        "--test-cameras",
        type=camera_ids,
        metavar="IDS",
        help="test camera ids, e.g. 1,5 (default: those the model's run chose, when its "
        "manifest records them, else the scene's own)",
    )


def add_device_argument(parser: argparse.ArgumentParser) -> None:
    """`--device`, where the model renders: a device name, or a usage error; whether this
    machine can use it is checked with `usable_device` before any work."""
    parser.add_argument(
        "--device", default="cpu", type=_device_name, help="cpu, cuda or cuda:N (default cpu)"
    )


def _device_name(text: str) -> str:
    """argparse type of `--device`: `text` when it names a device (`parse_device`)."""
    try:
        parse_device(text, "--device")
    except InputError:
        raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}") from None
    return text


def add_frame_stride_argument(parser: argparse.ArgumentParser, verb: str, note: str = "") -> None:
    """`--frame-stride N`: the command `verb`s (scores, renders, exports) every N-th frame."""
    parser.add_argument(
        "--frame-stride",
        type=int_at_least(1),
        default=1,
        metavar="N",
        help=f"{verb} every N-th frame (default 1{note})",
    )


def add_threads_argument(parser: argparse.ArgumentParser) -> None:
    """`--threads N`, torch's CPU thread count for the command (a run's `threads`), set with
    `set_threads` before any work."""
    parser.add_argument(
        "--threads",
        type=int_at_least(1, MAX_THREADS),
        metavar="N",
        help="torch CPU threads (default: torch's default; 1 is fastest on a busy machine)",
    )


def load_run_scene(args: argparse.Namespace, item: StoredArtifact) -> Scene:
    """The `--scene` folder loaded as `item`'s run loaded it: with the loader options its
    manifest records, those given on the command line taking their place. An error that only
    the recorded options cause names them and the manifest."""
    recorded = recorded_loading(item.manifest.provenance)
    given = {
        name: getattr(args, name) for name in FLAGGED_LOADING if getattr(args, name) is not None
    }
    used = sorted(recorded.keys() - given.keys())
    try:
        return load_scene(args.scene, **(recorded | given))
    except InputError as error:
        if not used:
            raise
        load_scene(args.scene, **given)  # fails alike without them: its error is not theirs
        flags = [f"--{name.replace('_', '-')}" for name in used if name in FLAGGED_LOADING]
        choose = f"; pass {' or '.join(flags)} to choose others" if flags else ""
        raise InputError(
            f"{error} (loaded with the {', '.join(used)} that {item.stage} "
            f"{item.key[:KEY_COLUMN_WIDTH]}'s manifest records for its run{choose})"
        ) from None


def model_artifact(store: ArtifactStore, key_prefix: str) -> tuple[StoredArtifact, Artifact]:
    """The stored model of `key_prefix`, refusing a stored evaluation (it holds no model)."""
    item = store.find(key_prefix)
    if item.stage == EVAL_STAGE:
        raise RelayGSError(
            f"{item.key[:KEY_COLUMN_WIDTH]} is a stored evaluation, not a model: "
            f"`show {key_prefix}` prints its metrics"
        )
    return item, store.load(item.stage, item.key)


def note_other_scene(
    items: Sequence[StoredArtifact], scene: Scene, args: argparse.Namespace
) -> None:
    """A stderr note for each model that was not trained on this scene as loaded here (the
    fingerprint in its manifest differs), saying why where the manifest tells: its test views,
    and so its scores, may not be the run's."""
    for item in items:
        trained_on = item.manifest.provenance.get("scene")
        if trained_on is not None and trained_on != scene.fingerprint:
            print(
                f"note: {item.stage} {item.key[:KEY_COLUMN_WIDTH]} was not trained on "
                f"{scene.root} as loaded here ({_why_other_scene(item, args)}",
                file=sys.stderr,
            )


def _why_other_scene(item: StoredArtifact, args: argparse.Namespace) -> str:
    """What differs from `item`'s run, a closing bracket, and what that means: the loader
    options given here, else (its manifest records the run's options, and they were used)
    the scene's files."""
    recorded = recorded_loading(item.manifest.provenance)
    if not recorded:  # written before manifests recorded the run's loader options
        return (
            "its files or loader options differ), so its test views may not be the run's: "
            "pass the run's --downscale and --test-cameras"
        )
    given = {name: getattr(args, name) for name in FLAGGED_LOADING}
    run_flags = {name: _as_typed(value) for name, value in recorded.items()}
    changed = [
        f"--{name.replace('_', '-')} (the run's: {run_flags.get(name, 'the default')})"
        for name, value in given.items()
        if value is not None and _as_typed(value) != run_flags.get(name)
    ]
    if changed:
        return f"given here: {', '.join(changed)}), so its test views are not the run's"
    return (
        "its run's loader options were used, so its files differ from those the run read: "
        "another copy of the scene, or an edited one), and its scores may not be the run's"
    )


def _as_typed(value: Any) -> str:
    """A loader option's value as its flag is typed, camera ids as the set they are (`1,5`, or
    `[]` for none), so that the same cameras in another order or repeated count as the same."""
    if isinstance(value, list | tuple):
        return ",".join(str(item) for item in sorted(set(value))) or "[]"
    return str(value)
