"""Bad scene input: each case is an InputError whose one-line message names file/field/value."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from relaygs.data import load_scene
from relaygs.errors import InputError


def _edit_meta(root: Path, name: str, edit: Callable[[dict], None]) -> None:
    path = root / name
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))


def _expect(root: Path, *fragments: str, **options) -> str:
    with pytest.raises(InputError) as caught:
        load_scene(root, **options)
    message = str(caught.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_missing_scene_folder(tmp_path: Path):
    _expect(tmp_path / "absent", "scene folder: ", "absent does not exist")


def test_folder_of_unknown_layout(tmp_path: Path):
    _expect(tmp_path, "unknown scene layout", "train_meta.json")


def test_missing_meta_file(tiny_synth_copy: Path):
    (tiny_synth_copy / "test_meta.json").unlink()
    _expect(tiny_synth_copy, "missing file", "test_meta.json")


def test_malformed_json(tiny_synth_copy: Path):
    (tiny_synth_copy / "train_meta.json").write_text('{"w": 32, "h": ')
    _expect(tiny_synth_copy, "train_meta.json", "malformed JSON", "line 1")


def test_frame_counts_that_disagree_between_fields(tiny_synth_copy: Path):
    _edit_meta(tiny_synth_copy, "train_meta.json", lambda meta: meta["k"].pop())
    _expect(tiny_synth_copy, "train_meta.json", "'k'", "T=5", "T=6")


def test_camera_counts_that_disagree_between_fields(tiny_synth_copy: Path):
    def drop_camera(meta: dict) -> None:
        for row in meta["w2c"]:
            row.pop()

    _edit_meta(tiny_synth_copy, "test_meta.json", drop_camera)
    _expect(tiny_synth_copy, "test_meta.json", "'w2c'", "C=3", "C=4")


def test_frame_counts_that_disagree_between_meta_files(tiny_synth_copy: Path):
    def drop_frame(meta: dict) -> None:
        for field in ("k", "w2c", "fn", "cam_id"):
            meta[field].pop()

    _edit_meta(tiny_synth_copy, "test_meta.json", drop_frame)
    _expect(tiny_synth_copy, "test_meta.json", "T=5", "T=6")


def test_wrong_matrix_shape(tiny_synth_copy: Path):
    def flatten(meta: dict) -> None:
        meta["k"] = [[[value for line in k for value in line] for k in row] for row in meta["k"]]

    _edit_meta(tiny_synth_copy, "train_meta.json", flatten)
    _expect(tiny_synth_copy, "'k'", "[T][C][3][3]")


def test_zero_focal_length(tiny_synth_copy: Path):
    def zero_fx(meta: dict) -> None:
        meta["k"][2][1][0][0] = 0.0

    _edit_meta(tiny_synth_copy, "train_meta.json", zero_fx)
    _expect(tiny_synth_copy, "train_meta.json: field 'k'", "fx, fy > 0")


def test_pose_that_is_not_rigid(tiny_synth_copy: Path):
    def scale_rotation(meta: dict) -> None:
        pose = meta["w2c"][0][3]
        pose[:3] = [[2.0 * value for value in line[:3]] + line[3:] for line in pose[:3]]

    _edit_meta(tiny_synth_copy, "test_meta.json", scale_rotation)
    _expect(tiny_synth_copy, "test_meta.json: field 'w2c'", "rigid world→camera")


def test_non_positive_image_size_field(tiny_synth_copy: Path):
    _edit_meta(tiny_synth_copy, "train_meta.json", lambda meta: meta.update(w=0))
    _expect(tiny_synth_copy, "train_meta.json", "'w'", "positive integer", "0")


def test_file_name_that_escapes_the_scene_root(tiny_synth_copy: Path):
    def escape(meta: dict) -> None:
        meta["fn"][2][1] = "../../../etc/passwd"

    _edit_meta(tiny_synth_copy, "train_meta.json", escape)
    _expect(tiny_synth_copy, "escapes the scene folder", "../../../etc/passwd")


def test_absolute_file_name_is_refused(tiny_synth_copy: Path):
    _edit_meta(
        tiny_synth_copy, "train_meta.json", lambda meta: meta["fn"][0].__setitem__(0, "/x.png")
    )
    _expect(tiny_synth_copy, "escapes the scene folder", "/x.png")


def test_image_whose_size_differs_from_w_h(tiny_synth_copy: Path):
    small = tiny_synth_copy / "ims" / "4" / "000001.png"
    shutil.copyfile(_png_of_size(tiny_synth_copy, 20, 10), small)
    _expect(tiny_synth_copy, "000001.png", "20x10", "expected 32x18")


def _png_of_size(root: Path, width: int, height: int) -> Path:
    path = root / "odd.png"
    cv2.imwrite(str(path), np.zeros((height, width, 3), np.uint8))
    return path


def test_unreadable_image(tiny_synth_copy: Path):
    (tiny_synth_copy / "ims" / "7" / "000003.png").write_bytes(b"this is not an image")
    _expect(tiny_synth_copy, "ims/7/000003.png", "not a readable image")


def test_missing_image(tiny_synth_copy: Path):
    (tiny_synth_copy / "ims" / "7" / "000003.png").unlink()
    _expect(tiny_synth_copy, "missing image file", "000003.png")


def test_empty_point_cloud(tiny_synth_copy: Path):
    np.savez(tiny_synth_copy / "init_pt_cld.npz", data=np.zeros((0, 7), np.float32))
    _expect(tiny_synth_copy, "init_pt_cld.npz", "non-empty")


def test_non_finite_point_cloud(tiny_synth_copy: Path):
    data = np.random.default_rng(0).random((50, 7)).astype(np.float32)
    data[3, 1] = np.nan
    np.savez(tiny_synth_copy / "init_pt_cld.npz", data=data)
    _expect(tiny_synth_copy, "init_pt_cld.npz", "non-finite")


def test_point_cloud_with_wrong_columns_or_key(tiny_synth_copy: Path):
    np.savez(tiny_synth_copy / "init_pt_cld.npz", data=np.zeros((5, 6), np.float32))
    _expect(tiny_synth_copy, "init_pt_cld.npz", "[N,7]")
    np.savez(tiny_synth_copy / "init_pt_cld.npz", points=np.zeros((5, 7), np.float32))
    _expect(tiny_synth_copy, "init_pt_cld.npz", "missing array 'data'")


def test_unknown_effect_in_scene_json(tiny_synth_copy: Path):
    path = tiny_synth_copy / "scene.json"
    declaration = json.loads(path.read_text())
    declaration["effects"] = ["nonrigid", "glitter"]
    path.write_text(json.dumps(declaration))
    _expect(tiny_synth_copy, "scene.json", "unknown effect 'glitter'")


@pytest.mark.parametrize(
    ("options", "fragment"),
    [
        ({"downscale": 0}, "downscale must be an integer >= 1"),
        ({"downscale": 1.5}, "downscale must be an integer >= 1"),
        ({"max_points": 0}, "max_points must be an integer >= 1"),
        ({"cache_mb": -1}, "cache_mb must be a number > 0"),
        ({"test_cameras": [99]}, "cameras [99] are not in the scene"),
        ({"effects": ["sparkle"]}, "unknown effect 'sparkle'"),
    ],
)
def test_bad_loader_options(tiny_synth_scene: Path, options: dict, fragment: str):
    _expect(tiny_synth_scene, fragment, **options)
