"""Loader for the PanopticSports layout (train/test meta JSON, ims/, seg/, init_pt_cld.npz)."""

from __future__ import annotations

import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from relaygs.data.camera import Camera, check_intrinsics, check_rigid
from relaygs.data.fingerprint import file_record, record_image
from relaygs.data.finite import FINITE, finite_in_float32
from relaygs.data.metafiles import SCENE_JSON, read_json
from relaygs.data.options import LoaderOptions, require_int, test_cameras_setting
from relaygs.data.points import PointCloud, point_cloud_from_arrays
from relaygs.data.scene import (
    Scene,
    View,
    assemble_scene,
    frame_time,
    hold_out,
    split_views,
)
from relaygs.errors import InputError

TRAIN_META = "train_meta.json"
TEST_META = "test_meta.json"
POINTS_FILE = "init_pt_cld.npz"
MAX_CAMERA_ID = 2**31 - 1  # largest camera id: ids must fit a signed 32-bit integer


@dataclass(frozen=True)
class PanopticMeta:
    """One meta file: image size and, per frame t and column c, K, w2c, file name, camera id."""

    path: Path
    width: int
    height: int
    K: np.ndarray
    w2c: np.ndarray
    fn: list[list[str]]
    cam_id: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.fn)


def load_panoptic(root: Path, options: LoaderOptions) -> Scene:
    """Load a Panoptic-layout folder; test_meta.json may be absent when `test_cameras` is set."""
    files = {
        name: file_record(root / name, root=root).sha256
        for name in (TRAIN_META, TEST_META, SCENE_JSON, POINTS_FILE)
        if (root / name).exists()
    }
    train = read_meta(root / TRAIN_META)
    metas = [train, *_test_meta(root, train, options.test_cameras)]
    cameras: dict[tuple, Camera] = {}
    entries = [view for meta in metas for view in _views(root, meta, files, cameras)]
    train_views, test_views = _split(entries, metas, options)
    points, content = _read_points(root / POINTS_FILE, options.max_points), {"files": files}
    return assemble_scene(
        root, "panoptic", train_views, test_views, train.num_frames, points, options, content
    )


def read_meta(path: Path, train: PanopticMeta | None = None) -> PanopticMeta:
    """Parse and check a meta file: every per-view field [T][C] with equal T, C; a test meta's
    w/h must match `train`'s, as its intrinsics are checked against them."""
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a JSON object with fields w, h, k, w2c, fn, cam_id")
    width, height = (
        require_int(f"field '{key}'", meta.get(key), minimum=1, prefix=f"{path}: ") for key in "wh"
    )
    if train is not None and (train.width, train.height) != (width, height):
        raise InputError(
            f"{path}: w/h {width}x{height} differ from {train.path} ({train.width}x{train.height})"
        )
    fn = _file_names(meta, path)
    shape = (len(fn), len(fn[0]))
    K = _array_field(meta, "k", path, shape, (3, 3))
    w2c = _array_field(meta, "w2c", path, shape, (4, 4))
    cam_id = _array_field(meta, "cam_id", path, shape, (), integer=True)
    _check_unique_cameras(cam_id, path)
    check_intrinsics(K, f"{path}: field 'k'", at=_view_at(cam_id), size=(width, height))
    check_rigid(w2c, f"{path}: field 'w2c'", at=_view_at(cam_id))
    return PanopticMeta(path, width, height, K, w2c, fn, cam_id)


def _view_at(cam_id: np.ndarray) -> Callable[[tuple[int, ...]], str]:
    """How a meta file's check names the view at [t][c]: its frame, column and camera id."""
    return lambda index: (
        f" at [{index[0]}][{index[1]}] (frame {index[0]}, column {index[1]}: camera "
        f"{cam_id[index]})"
    )


def _file_names(meta: dict, path: Path) -> list[list[str]]:
    fn = meta.get("fn")
    ok = isinstance(fn, list) and fn and all(isinstance(row, list) and row for row in fn)
    if not ok or any(not isinstance(name, str) for row in fn for name in row):
        raise InputError(f"{path}: field 'fn' must be a non-empty [T][C] list of file names")
    widths = {len(row) for row in fn}
    if len(widths) != 1:
        raise InputError(f"{path}: field 'fn' rows have different camera counts {sorted(widths)}")
    for t, row in enumerate(fn):
        for c, name in enumerate(row):
            if _names_no_scene_file(name):
                raise InputError(
                    f"{path}: field 'fn' at [{t}][{c}] is {name!r}, expected an image file name "
                    "inside the scene folder"
                )
    return fn


def _names_no_scene_file(name: str) -> bool:
    """Whether `name` is empty, absolute, climbs out of ims/, or is no path text (a NUL, or a
    lone surrogate, which JSON may hold)."""
    try:
        os.fsencode(name)
    except UnicodeEncodeError:
        return True
    climbs = os.path.normpath(os.path.join("ims", name)).split(os.sep)[0] == ".."
    return "\0" in name or os.path.normpath(name) == "." or os.path.isabs(name) or climbs


def _array_field(
    meta: dict,
    name: str,
    path: Path,
    shape: tuple[int, int],
    trailing: tuple[int, ...],
    *,
    integer: bool = False,
) -> np.ndarray:
    expected = "[T][C]" + "".join(f"[{size}]" for size in trailing)
    if name not in meta:
        raise InputError(f"{path}: missing field '{name}' (expected {expected})")
    try:
        array = np.asarray(meta[name], dtype=np.float64)
    except (ValueError, TypeError):
        raise InputError(f"{path}: field '{name}' must be a {expected} array of numbers") from None
    if array.shape[2:] != trailing or array.ndim != 2 + len(trailing):
        raise InputError(
            f"{path}: field '{name}' has shape {list(array.shape)}, expected {expected}"
        )
    if array.shape[:2] != shape:
        raise InputError(
            f"{path}: field '{name}' has T={array.shape[0]}, C={array.shape[1]} but 'fn' has "
            f"T={shape[0]}, C={shape[1]}"
        )
    if not finite_in_float32(array).all():
        raise InputError(f"{path}: field '{name}' holds values not finite in float32 ({FINITE})")
    if integer:
        if (array != np.round(array)).any() or (array < 0).any() or (array > MAX_CAMERA_ID).any():
            raise InputError(f"{path}: field '{name}' must hold integers in 0..{MAX_CAMERA_ID}")
        return array.astype(np.int64)
    return array


def _check_unique_cameras(cam_id: np.ndarray, path: Path) -> None:
    """Refuse a camera id twice in one frame: one camera would have two views at one time."""
    for t, row in enumerate(cam_id.tolist()):
        for c, camera_id in enumerate(row):
            if camera_id in row[:c]:
                raise InputError(
                    f"{path}: field 'cam_id' lists camera {camera_id} in columns "
                    f"{row.index(camera_id)} and {c} of frame {t}; expected one column per camera"
                )


def _test_meta(
    root: Path, train: PanopticMeta, test_cameras: tuple[int, ...] | None
) -> list[PanopticMeta]:
    """[test meta], or [] when it is absent and `test_cameras` names the held-out cameras."""
    path = root / TEST_META
    if not path.exists():
        if test_cameras is not None:
            return []
        raise InputError(
            f"missing file: {path}; it lists the test cameras, so without it name some of "
            f"{TRAIN_META}'s: {test_cameras_setting(None)}"
        )
    test = read_meta(path, train)
    _check_compatible(train, test)
    return [test]


def _camera_ids(meta: PanopticMeta) -> set[int]:
    return set(meta.cam_id.ravel().tolist())


def _check_compatible(train: PanopticMeta, test: PanopticMeta) -> None:
    if train.num_frames != test.num_frames:
        raise InputError(
            f"{test.path}: T={test.num_frames} frames but {train.path} has T={train.num_frames}"
        )
    shared = _camera_ids(train) & _camera_ids(test)
    if shared:
        raise InputError(
            f"{test.path}: camera ids {sorted(shared)} also appear in {train.path}; "
            "train and test cameras must differ"
        )


def _views(
    root: Path, meta: PanopticMeta, files: dict[str, str], cameras: dict[tuple, Camera]
) -> list[View]:
    has_masks = (root / "seg").is_dir()
    views = []
    for t, row in enumerate(meta.fn):
        for c, name in enumerate(row):
            image_path = root / os.path.normpath(os.path.join("ims", name))
            size, origin = (meta.width, meta.height), f"w/h in {meta.path.name}"
            record_image(image_path, size, files, root, "image", origin)
            mask_path = None
            if has_masks:
                mask_path = (root / os.path.normpath(os.path.join("seg", name))).with_suffix(".png")
                record_image(mask_path, size, files, root, "mask", origin)
            camera = _camera(meta, t, c, cameras)
            views.append(View(camera, t, frame_time(t, meta.num_frames), image_path, mask_path))
    return views


def _camera(meta: PanopticMeta, t: int, c: int, cameras: dict[tuple, Camera]) -> Camera:
    camera_id = int(meta.cam_id[t, c])
    K = meta.K[t, c].astype(np.float32)
    w2c = meta.w2c[t, c].astype(np.float32)
    key = (camera_id, K.tobytes(), w2c.tobytes())
    if key not in cameras:
        cameras[key] = Camera(
            camera_id, torch.from_numpy(K), torch.from_numpy(w2c), meta.width, meta.height
        )
    return cameras[key]


def _split(
    views: list[View], metas: list[PanopticMeta], options: LoaderOptions
) -> tuple[list[View], list[View]]:
    """Hold out the `test_cameras` option's ids, else test_meta.json's (metas[1]) cameras."""
    if options.test_cameras is None:
        return split_views(views, _camera_ids(metas[1]), metas[0].path)
    known = set().union(*map(_camera_ids, metas))
    where = f"the scene (camera ids: {sorted(known)}); hold out only cameras it has (or none)"
    source = f"{options.prefix}test_cameras"
    return hold_out(views, options.test_cameras, known, metas[0].path, source, where)


def _read_points(path: Path, max_points: int) -> PointCloud:
    data = _points_array(path)
    if data.ndim != 2 or data.shape[1] != 7:
        raise InputError(
            f"{path}: array 'data' has shape {list(data.shape)}, expected [N,7] xyz, rgb, seg"
        )
    if data.dtype.kind not in "iuf":
        raise InputError(f"{path}: array 'data' has dtype {data.dtype}, expected real numbers")
    return point_cloud_from_arrays(
        data[:, :3], data[:, 3:6], data[:, 6] > 0.5, source=str(path), max_points=max_points
    )


def _points_array(path: Path) -> np.ndarray:
    """Array 'data' of the .npz at `path`, never unpickling; any other file is refused."""
    if not path.exists():
        raise InputError(f"missing file: {path}")
    unreadable = InputError(f"{path}: not a readable .npz point cloud")
    if not zipfile.is_zipfile(path):
        raise unreadable
    try:
        with np.load(path, allow_pickle=False) as archive:
            data = archive["data"] if "data" in archive.files else None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        raise unreadable from None
    if data is None:
        raise InputError(f"{path}: missing array 'data' (expected [N,7] xyz, rgb, seg)")
    if not isinstance(data, np.ndarray):
        raise unreadable
    return data
