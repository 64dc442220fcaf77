"""What `artifacts eval`, `gap`, `render` and `ply` share: the stored model a key names, its
scene loaded as its run loaded it (noted when not), and their options."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from relaygs.app.evaluation import EVAL_STAGE
from relaygs.app.plan import MAX_THREADS
from relaygs.app.scenes import recorded_loading
from relaygs.cli import camera_ids, int_at_least, path_argument
from relaygs.data import Scene, load_scene
from relaygs.device import parse_device
from relaygs.errors import InputError, RelayGSError
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.store import ArtifactStore, StoredArtifact, checked_key_prefix

KEY_COLUMN_WIDTH = 16
KEY_HELP = "full key or a unique prefix (at least 4 hex digits)"
FLAGGED_LOADING = ("downscale", "test_cameras")  # the others always come from the manifest


def key_prefix(text: str) -> str:
    """argparse type of a key argument: a malformed prefix is a usage error (exit 2)."""
    try:
        checked_key_prefix(text)
    except InputError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def add_model_arguments(
    parser: argparse.ArgumentParser, verb: str, scene: bool = True, stride_note: str = ""
) -> None:
    """KEY; with `scene`, `--scene` and the loader options that load it as the run did, and
    `--device`; then `--threads` and `--frame-stride` (the command `verb`s every N-th frame)."""
    parser.add_argument("key", type=key_prefix, help=KEY_HELP)
    if scene:
        parser.add_argument(
            "--scene", type=path_argument, required=True, help="the scene folder it was trained on"
        )
        parser.add_argument(
            "--downscale",
            type=int_at_least(1),
            help="the run's scene.loader.downscale (default: the one the model's manifest "
            "records, else 1)",
        )
        parser.add_argument(
            "--test-cameras",
            type=camera_ids,
            metavar="IDS",
            help="test camera ids, e.g. 1,5 (default: those the model's run chose, when its "
            "manifest records them, else the scene's own)",
        )
        parser.add_argument(
            "--device", default="cpu", type=_device_name, help="cpu, cuda or cuda:N (default cpu)"
        )
    parser.add_argument(
        "--threads",
        type=int_at_least(1, MAX_THREADS),
        metavar="N",
        help="torch CPU threads (default: torch's default; 1 is fastest on a busy machine)",
    )
    parser.add_argument(
        "--frame-stride",
        type=int_at_least(1),
        default=1,
        metavar="N",
        help=f"{verb} every N-th frame (default 1{stride_note})",
    )


def _device_name(text: str) -> str:
    """argparse type of `--device`: `text` when it names a device (`parse_device`); whether
    this machine can use it is checked with `usable_device` before any work."""
    try:
        parse_device(text, "--device")
    except InputError:
        raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}") from None
    return text


def load_run_scene(args: argparse.Namespace, item: StoredArtifact) -> Scene:
    """`--scene` loaded with the loader options `item`'s manifest records, those given here
    taking their place; an error only the recorded ones cause names them and the manifest."""
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


def note_other_scene(items: Sequence[StoredArtifact], scene: Scene) -> None:
    """A stderr note for each model whose manifest's scene fingerprint is not this scene's as
    loaded here: its test views, and so its scores, may not be the run's."""
    for item in items:
        trained_on = item.manifest.provenance.get("scene")
        if trained_on is not None and trained_on != scene.fingerprint:
            print(
                f"note: {item.stage} {item.key[:KEY_COLUMN_WIDTH]} was not trained on "
                f"{scene.root} as loaded here (its files, or the --downscale or --test-cameras "
                "given here, differ from its run's), so its test views, and scores, may not "
                "be the run's",
                file=sys.stderr,
            )
