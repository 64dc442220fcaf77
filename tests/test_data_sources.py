"""Scene files that are not regular files inside the scene folder are refused in one line."""

from __future__ import annotations

import os
import shutil
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from relaygs.data import load_scene
from relaygs.data.export import export_multiview
from relaygs.errors import InputError

SECONDS_TO_REFUSE = 20.0
"""A refusal takes well under a second; a read that blocks (a FIFO) or never ends (/dev/zero)
would take forever."""


def _refusal(root: Path) -> str:
    """The one-line InputError `load_scene(root)` ends with, failing the test when it does not
    end within SECONDS_TO_REFUSE (the loader then runs on in a daemon thread)."""
    outcome: list[BaseException | None] = []

    def load() -> None:
        try:
            load_scene(root)
            outcome.append(None)
        except BaseException as error:
            outcome.append(error)

    worker = threading.Thread(target=load, daemon=True)
    worker.start()
    worker.join(SECONDS_TO_REFUSE)
    assert outcome, f"loading {root} did not end within {SECONDS_TO_REFUSE} s"
    error = outcome[0]
    assert isinstance(error, InputError), repr(error)
    assert "\n" not in str(error)
    return str(error)


IMAGE = Path("ims") / "4" / "000001.png"


def _fifo(tmp_path: Path) -> Path:
    os.mkfifo(tmp_path / "pipe")
    return tmp_path / "pipe"


def _linked(name: str | Path, target: Callable[[Path], Path | str]):
    """A damage: replace scene file `name` by a link to `target(tmp_path)`."""

    def damage(root: Path, tmp_path: Path) -> tuple[Path, Path]:
        (root / name).unlink()
        (root / name).symlink_to(target(tmp_path))
        return root, root / name

    return damage


def _moved_out(name: str, multiview: bool = False):
    """A damage: move scene file or folder `name` out of the scene and link it back in."""

    def damage(root: Path, tmp_path: Path) -> tuple[Path, Path]:
        if multiview:
            root = export_multiview(load_scene(root), tmp_path / "multiview")
        path = root / name
        path.symlink_to(Path(shutil.move(path, tmp_path / path.name)))
        return root, path

    return damage


@pytest.mark.parametrize(
    ("damage", "named"),
    [
        (_linked(IMAGE, _fifo), "named pipe"),
        (_linked(IMAGE, lambda _: "/dev/zero"), "character device"),
        (_linked("train_meta.json", _fifo), "named pipe"),
        (_moved_out("ims/4"), "outside the scene folder"),
        (_moved_out("init_pt_cld.npz"), "outside the scene folder"),
        (_moved_out("cam07", multiview=True), "outside the scene folder"),
        (_moved_out("sparse/0/cameras.bin", multiview=True), "outside the scene folder"),
    ],
    ids=["fifo image", "device image", "fifo meta", "image folder", "points", "camera", "model"],
)
def test_a_scene_file_that_is_no_regular_file_inside_is_refused(
    tiny_synth_copy: Path, tmp_path: Path, damage, named: str
):
    root, path = damage(tiny_synth_copy, tmp_path)
    message = _refusal(root)
    assert str(path) in message and named in message


def test_a_symlink_that_stays_inside_the_scene_is_followed(tiny_synth_copy: Path):
    image = tiny_synth_copy / IMAGE
    shutil.move(image, tiny_synth_copy / "moved.png")
    image.symlink_to("../../moved.png")
    assert load_scene(tiny_synth_copy).num_frames == 6
