"""Loader for multi-view video with COLMAP poses: camXX/frame_XXXXX.(jpg|png) + a sparse model."""

from __future__ import annotations

import re
from itertools import pairwise
from pathlib import Path

import numpy as np
import torch

from relaygs.data.camera import Camera, check_intrinsics
from relaygs.data.colmap import (
    ColmapCamera,
    ColmapModel,
    model_suffix,
    read_model,
)
from relaygs.data.fingerprint import file_record, record_image
from relaygs.data.finite import finite_in_float32
from relaygs.data.metafiles import SCENE_JSON, declared_test_cameras
from relaygs.data.options import LoaderOptions
from relaygs.data.points import point_cloud_from_arrays
from relaygs.data.scene import (
    Scene,
    View,
    assemble_scene,
    frame_time,
    hold_out,
    split_views,
)
from relaygs.errors import InputError

CAMERA_FOLDER = re.compile(r"^cam(\d+)$")
FRAME_FILE = re.compile(r"^frame_(\d+)\.(jpg|jpeg|png)$", re.IGNORECASE)
MODEL_FOLDERS = ("sparse/0", "sparse", "sparse_", "colmap/sparse/0")
DEFAULT_TEST_CAMERAS = (0, 10, 20, 30)
MASK_FOLDER = "seg"
_COLMAP_SIZE = "the COLMAP camera's width/height"
MISSING_FRAMES_LISTED = 3  # how many of the frame files a camera folder lacks its error names

# COLMAP model → parameter indices of fx, fy, cx, cy; later parameters are distortion terms.
_PINHOLE_PARAMS: dict[str, tuple[int, int, int, int]] = {
    "SIMPLE_PINHOLE": (0, 0, 1, 2),
    "PINHOLE": (0, 1, 2, 3),
    "SIMPLE_RADIAL": (0, 0, 1, 2),
    "RADIAL": (0, 0, 1, 2),
    "OPENCV": (0, 1, 2, 3),
    "FULL_OPENCV": (0, 1, 2, 3),
}


def camera_folders(root: Path) -> list[Path]:
    """The camXX folders of `root`, ordered by their number (camera id = position in this list)."""
    folders = [p for p in root.iterdir() if p.is_dir() and CAMERA_FOLDER.match(p.name)]
    return sorted(
        folders, key=lambda folder: (int(CAMERA_FOLDER.match(folder.name)[1]), folder.name)
    )


def load_multiview(root: Path, options: LoaderOptions) -> Scene:
    """Load camXX/ frame folders posed by the COLMAP model of their first frame."""
    folders = camera_folders(root)
    frames = _frame_files(folders)
    model_folder = _find_model(root)
    files = {
        path.relative_to(root).as_posix(): file_record(path, root=root).sha256
        for path in sorted(model_folder.iterdir())
        if path.is_file() and path.stem in ("cameras", "images", "points3D")
    }
    model = read_model(model_folder)
    if (root / SCENE_JSON).exists():
        files[SCENE_JSON] = file_record(root / SCENE_JSON, root=root).sha256
    declared = declared_test_cameras(root)
    cameras = _cameras(folders, model, model_folder)
    views = _views(root, folders, frames, cameras, files)
    train_views, test_views = _split(views, len(folders), options, declared, root)
    points = point_cloud_from_arrays(
        model.xyz,
        model.rgb.astype(np.float64) / 255.0,
        np.zeros(len(model.xyz), dtype=bool),
        source=str(model_folder / f"points3D{model_suffix(model_folder)}"),
        max_points=options.max_points,
    )
    content: dict = {"files": files}
    if declared is not None and options.test_cameras is None:
        # scene.json's split enters the key: older relaygs read the same file as the default split
        content["declared_test_cameras"] = list(declared)
    return assemble_scene(
        root, "multiview", train_views, test_views, len(frames[0]), points, options, content
    )


def _frame_files(folders: list[Path]) -> list[list[Path]]:
    """Each camera folder's frame files in order; a camera lacking some is refused naming them."""
    cameras: dict[Path, dict[int, Path]] = {}
    for folder in folders:
        numbered = _numbered_frames(folder)
        if not numbered:
            raise InputError(f"{folder}: no frame_XXXXX.(jpg|png) images")
        cameras[folder] = dict(numbered)
    every = set().union(*cameras.values())
    for folder, frames in cameras.items():
        missing = sorted(every - frames.keys())
        if missing:
            raise InputError(_missing_frames(folder, missing, cameras))
    return [list(frames.values()) for frames in cameras.values()]


def _missing_frames(folder: Path, missing: list[int], cameras: dict[Path, dict[int, Path]]) -> str:
    """One line naming the frame files `folder` lacks (the first few, each named as the first
    camera holding it names it) and the frame range of the first camera holding the first."""
    holder, frames = next((other, held) for other, held in cameras.items() if missing[0] in held)
    names = [
        next(held[number] for held in cameras.values() if number in held).name
        for number in missing[:MISSING_FRAMES_LISTED]
    ]
    more = len(missing) - len(names)
    listed = ", ".join(names) + (f" and {more} more" if more else "")
    return (
        f"{folder}: lacks {listed} (frames {min(frames)}..{max(frames)} in {holder.name}); "
        "every camera needs the same frame numbers"
    )


def _numbered_frames(folder: Path) -> list[tuple[int, Path]]:
    """(number, path) of a folder's frame files in order; two files of one number are refused."""
    numbered = sorted(
        (int(match[1]), path) for path in folder.iterdir() if (match := FRAME_FILE.match(path.name))
    )
    for (number, first), (other, second) in pairwise(numbered):
        if number == other:
            raise InputError(
                f"{folder}: {first.name} and {second.name} are both frame {number}; expected "
                "one image per frame number"
            )
    return numbered


def _find_model(root: Path) -> Path:
    for candidate in MODEL_FOLDERS:
        if model_suffix(root / candidate) is not None:
            return root / candidate
    raise InputError(
        f"{root}: no COLMAP model found; expected cameras, images, points3D (.bin or .txt) in "
        + " or ".join(MODEL_FOLDERS)
    )


def _cameras(folders: list[Path], model: ColmapModel, model_folder: Path) -> list[Camera]:
    """One camera per camXX folder, posed by the one registered image named after it."""
    by_folder = {}
    for image in model.images.values():
        match = re.search(r"cam\d+", image.name)
        if match is None:
            continue
        if match[0] in by_folder:
            raise InputError(
                f"{model_folder}: images {by_folder[match[0]].name!r} and {image.name!r} both "
                f"map to camera folder {match[0]}; the rig is fixed, so the model must register "
                "one image per camera: run COLMAP on one frame of each (python -m relaygs.frames "
                "prints the commands)"
            )
        by_folder[match[0]] = image
    cameras = []
    for camera_id, folder in enumerate(folders):
        image = by_folder.get(folder.name)
        if image is None:
            raise InputError(
                f"{model_folder}: no registered image named after camera folder {folder.name} "
                f"(expected e.g. '{folder.name}.jpg')"
            )
        if image.camera_id not in model.cameras:
            raise InputError(
                f"{model_folder}: image {image.name!r} uses unknown camera {image.camera_id}"
            )
        pose = np.array([*image.qvec, *image.tvec], dtype=np.float64)
        if not (finite_in_float32(pose).all() and np.linalg.norm(pose[:4]) > 0):
            raise InputError(
                f"{model_folder}: image {image.name!r} has pose qvec {list(image.qvec)} tvec "
                f"{list(image.tvec)}; expected values finite in float32 and a non-zero quaternion"
            )
        intrinsics = model.cameras[image.camera_id]
        K = _intrinsics(intrinsics, model_folder)
        w2c = torch.from_numpy(image.w2c().astype(np.float32))
        cameras.append(Camera(camera_id, K, w2c, intrinsics.width, intrinsics.height))
    return cameras


def _intrinsics(camera: ColmapCamera, model_folder: Path) -> torch.Tensor:
    """K of a COLMAP camera without distortion; errors name the cameras file it came from."""
    source = model_folder / f"cameras{model_suffix(model_folder)}"
    indices = _PINHOLE_PARAMS.get(camera.model)
    if indices is None:
        raise InputError(
            f"{source}: camera {camera.camera_id} uses model {camera.model}; "
            f"supported: {', '.join(_PINHOLE_PARAMS)} (undistort fisheye images first)"
        )
    distortion = camera.params[max(indices) + 1 :]
    if any(abs(value) > 1e-9 for value in distortion):
        raise InputError(
            f"{source}: camera {camera.camera_id} ({camera.model}) has non-zero distortion "
            f"{list(distortion)}; undistort the images first (colmap image_undistorter)"
        )
    fx, fy, cx, cy = (camera.params[index] for index in indices)
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    where = f"{source}: camera {camera.camera_id} ({camera.model})"
    check_intrinsics(K, where, size=(camera.width, camera.height))
    return torch.from_numpy(K.astype(np.float32))


def _views(
    root: Path,
    folders: list[Path],
    frames: list[list[Path]],
    cameras: list[Camera],
    files: dict[str, str],
) -> list[View]:
    num_frames = len(frames[0])
    has_masks = (root / MASK_FOLDER).is_dir()
    views = []
    for folder, paths, camera in zip(folders, frames, cameras, strict=True):
        for frame, image_path in enumerate(paths):
            size = (camera.width, camera.height)
            record_image(image_path, size, files, root, "image", _COLMAP_SIZE)
            mask_path = None
            if has_masks:
                mask_path = root / MASK_FOLDER / folder.name / f"{image_path.stem}.png"
                record_image(mask_path, size, files, root, "mask", _COLMAP_SIZE)
            views.append(View(camera, frame, frame_time(frame, num_frames), image_path, mask_path))
    return views


def _split(
    views: list[View],
    num_cameras: int,
    options: LoaderOptions,
    declared: tuple[int, ...] | None,
    root: Path,
) -> tuple[list[View], list[View]]:
    """Hold out the `test_cameras` option's ids, else scene.json's `declared` ones, else the
    DEFAULT_TEST_CAMERAS that exist; explicit or declared ids must all exist."""
    if options.test_cameras is not None:
        ids, source = options.test_cameras, f"{options.prefix}test_cameras"
        fix = "hold out only cameras it has (or none)"
    elif declared is not None:
        ids, source = declared, f"{root / SCENE_JSON} field 'test_cameras'"
        fix = "correct that field, or override it"
    else:
        defaults = {camera_id for camera_id in DEFAULT_TEST_CAMERAS if camera_id < num_cameras}
        return split_views(views, defaults, root)
    where = f"{root} (camera ids 0..{num_cameras - 1}, one per camXX folder); {fix}"
    return hold_out(views, ids, set(range(num_cameras)), root, source, where)
