"""Scene files that are not regular files inside the scene folder are refused in one line."""

from __future__ import annotations

import os
import shutil
import threading
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


def _replace_with_link(path: Path, target: Path | str) -> None:
    path.unlink()
    path.symlink_to(target)


def test_an_image_that_is_a_fifo_is_refused_not_waited_on(tiny_synth_copy: Path, tmp_path: Path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    image = tiny_synth_copy / "ims" / "4" / "000001.png"
    _replace_with_link(image, fifo)
    message = _refusal(tiny_synth_copy)
    assert str(image) in message and "named pipe" in message


def test_an_image_that_is_a_device_is_refused_not_read_without_end(tiny_synth_copy: Path):
    image = tiny_synth_copy / "ims" / "4" / "000001.png"
    _replace_with_link(image, "/dev/zero")
    message = _refusal(tiny_synth_copy)
    assert str(image) in message and "character device" in message


def test_a_meta_file_that_is_a_fifo_is_refused(tiny_synth_copy: Path):
    meta = tiny_synth_copy / "train_meta.json"
    meta.unlink()
    os.mkfifo(meta)
    message = _refusal(tiny_synth_copy)
    assert str(meta) in message and "named pipe" in message


def test_a_symlinked_image_folder_outside_the_scene_is_refused(
    tiny_synth_copy: Path, tmp_path: Path
):
    folder = tiny_synth_copy / "ims" / "4"
    outside = Path(shutil.move(folder, tmp_path / "elsewhere"))
    folder.symlink_to(outside)
    message = _refusal(tiny_synth_copy)
    assert str(folder) in message and "outside the scene folder" in message


def test_a_symlink_that_stays_inside_the_scene_is_followed(tiny_synth_copy: Path):
    image = tiny_synth_copy / "ims" / "4" / "000001.png"
    shutil.move(image, tiny_synth_copy / "moved.png")
    image.symlink_to("../../moved.png")
    assert load_scene(tiny_synth_copy).num_frames == 6


def test_a_symlinked_camera_folder_outside_a_multiview_scene_is_refused(
    tiny_synth_scene: Path, tmp_path: Path
):
    root = export_multiview(load_scene(tiny_synth_scene), tmp_path / "multiview")
    camera = root / "cam07"
    outside = Path(shutil.move(camera, tmp_path / "cam07"))
    camera.symlink_to(outside)
    message = _refusal(root)
    assert str(camera / "frame_00000.png") in message and "outside the scene folder" in message


@pytest.mark.parametrize("name", ["cameras.bin", "init_pt_cld.npz"])
def test_model_and_point_files_outside_the_scene_are_refused(
    tiny_synth_scene: Path, tiny_synth_copy: Path, tmp_path: Path, name: str
):
    if name == "cameras.bin":
        root = export_multiview(load_scene(tiny_synth_scene), tmp_path / "multiview")
        path = root / "sparse" / "0" / name
    else:
        root, path = tiny_synth_copy, tiny_synth_copy / name
    outside = Path(shutil.move(path, tmp_path / name))
    path.symlink_to(outside)
    message = _refusal(root)
    assert str(path) in message and "outside the scene folder" in message
