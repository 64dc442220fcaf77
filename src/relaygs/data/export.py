"""Write a loaded scene in the multi-view layout (camXX/ frames + COLMAP model), e.g. to run a
synthetic scene through the COLMAP loader or to hand it to tools that expect that layout."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from relaygs.data.camera import Camera
from relaygs.data.colmap import (
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    rotation_to_qvec,
    write_model,
)
from relaygs.data.metafiles import SCENE_JSON, scene_declaration
from relaygs.data.multiview import MASK_FOLDER
from relaygs.data.scene import Scene
from relaygs.errors import InputError


def export_multiview(scene: Scene, out_dir: str | Path, *, binary: bool = True) -> Path:
    """Copy `scene`'s full-resolution frames to out_dir/camXX/frame_XXXXX.* and write its rig
    and points as a COLMAP model in out_dir/sparse/0 (binary or text). Needs a fixed rig."""
    out = Path(out_dir)
    views = sorted(
        scene.full_train_views + scene.full_test_views,
        key=lambda view: (view.camera.camera_id, view.frame),
    )
    cameras = _fixed_rig(scene, views)
    images, colmap_cameras = {}, {}
    for index, camera in enumerate(cameras, start=1):
        params = tuple(camera.K[[0, 1, 0, 1], [0, 1, 2, 2]].tolist())
        colmap_cameras[index] = ColmapCamera(index, "PINHOLE", camera.width, camera.height, params)
        w2c = camera.w2c.double().numpy()
        qvec, tvec = tuple(rotation_to_qvec(w2c[:3, :3]).tolist()), tuple(w2c[:3, 3].tolist())
        suffix = next(view.image_path.suffix for view in views if view.camera is camera)
        images[index] = ColmapImage(index, qvec, tvec, index, f"cam{index - 1:02d}{suffix}")
    index_of = {camera.camera_id: index for index, camera in enumerate(cameras)}
    for view in views:
        folder = f"cam{index_of[view.camera.camera_id]:02d}"
        name = f"frame_{view.frame:05d}"
        _copy(view.image_path, out / folder / f"{name}{view.image_path.suffix}")
        if view.mask_path is not None:
            _copy(view.mask_path, out / MASK_FOLDER / folder / f"{name}.png")
    rgb = np.round(scene.points.rgb.double().numpy() * 255.0).astype(np.uint8)
    model = ColmapModel(colmap_cameras, images, scene.points.xyz.double().numpy(), rgb)
    write_model(out / "sparse" / "0", model, binary=binary)
    # the source's scene.json with its test cameras renumbered: the export keeps its split
    declaration = scene_declaration(scene.root) or {}
    test_ids = {index_of[view.camera.camera_id] for view in scene.full_test_views}
    declaration["test_cameras"] = sorted(test_ids)
    (out / SCENE_JSON).write_text(json.dumps(declaration, indent=1) + "\n", encoding="utf-8")
    return out


def _fixed_rig(scene: Scene, views: list) -> list[Camera]:
    """One camera per id, by id; one whose pose or K varies, or that misses frames, is refused."""
    cameras: dict[int, Camera] = {}
    frames: dict[int, set[int]] = {}
    for view in views:
        frames.setdefault(view.camera.camera_id, set()).add(view.frame)
        known = cameras.setdefault(view.camera.camera_id, view.camera)
        same = known is view.camera or (
            bool((known.K == view.camera.K).all()) and bool((known.w2c == view.camera.w2c).all())
        )
        if not same:
            raise InputError(
                f"{scene.root}: camera {view.camera.camera_id} changes over time; the multi-view "
                "layout needs a fixed rig"
            )
    for camera_id, seen in sorted(frames.items()):
        if len(seen) != scene.num_frames:
            raise InputError(
                f"{scene.root}: camera {camera_id} is in {len(seen)} of the {scene.num_frames} "
                "frames; the multi-view layout needs every camera in every frame"
            )
    return [cameras[camera_id] for camera_id in sorted(cameras)]


def _copy(source: Path, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
