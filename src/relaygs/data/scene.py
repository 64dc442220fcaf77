"""The scene model every stage consumes: views (camera + frame + files), points and effects."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from relaygs.data.cache import TensorCache
from relaygs.data.camera import Camera, near_plane_for
from relaygs.data.fingerprint import digest
from relaygs.data.imageio import read_mask, read_rgb
from relaygs.data.metafiles import declared_effects
from relaygs.data.options import LoaderOptions, require_int, test_cameras_setting
from relaygs.data.points import PointCloud
from relaygs.errors import InputError

SAME_POSITION = 1e-6
"""Cameras whose centres spread less than this fraction of the point cloud share one position."""
MIN_IMAGE_SIDE = 4
"""Fewest pixels a side a loaded view may have: a smaller image shows no scene to fit."""


@dataclass(frozen=True)
class View:
    """One image of the capture: a camera at a frame (time = frame / (T − 1), 0 when T = 1)."""

    camera: Camera
    frame: int
    time: float
    image_path: Path
    mask_path: Path | None = None


def frame_time(frame: int, num_frames: int) -> float:
    """Normalised time of a frame: frame / (T − 1) in [0, 1], 0 for a single-frame scene."""
    return frame / (num_frames - 1) if num_frames > 1 else 0.0


@dataclass(frozen=True, eq=False)
class Scene:
    """A loaded scene; images and masks load lazily through a bounded cache. `fingerprint` covers
    every input file and content option (not the cache budget), so artifacts follow the data."""

    name: str
    root: Path
    format: str
    train_views: list[View]
    test_views: list[View]
    num_frames: int
    points: PointCloud
    effects: frozenset[str]
    extent: float
    downscale: int
    content_digest: str
    cache: TensorCache = field(repr=False)
    full_train_views: list[View] = field(repr=False)
    full_test_views: list[View] = field(repr=False)

    @property
    def fingerprint(self) -> str:
        """sha256 hex of the input content and every content-relevant loader option."""
        return digest({"content": self.content_digest, "downscale": self.downscale})

    def image(self, view: View) -> torch.Tensor:
        """The view's image as float32 [H,W,3] in [0,1] at the camera's size (shared: read-only)."""
        key = ("rgb", view.image_path, view.camera.width, view.camera.height)
        return self.cache.get(key, lambda: torch.from_numpy(read_rgb(*key[1:])))

    def mask(self, view: View) -> torch.Tensor | None:
        """The view's foreground mask as bool [H,W] (True = foreground), or None without masks."""
        if view.mask_path is None:
            return None
        camera, path = view.camera, view.mask_path
        key = ("mask", path, camera.width, camera.height)
        return self.cache.get(key, lambda: torch.from_numpy(read_mask(path, *key[2:])))

    def views_at(self, frame: int, split: str = "train") -> list[View]:
        """All views of one frame in `split` ("train", "test" or "all"), ordered by camera id."""
        if split not in ("train", "test", "all"):
            raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")
        views = [] if split == "test" else self.train_views
        views = views + ([] if split == "train" else self.test_views)
        selected = [view for view in views if view.frame == frame]
        return sorted(selected, key=lambda view: view.camera.camera_id)

    @property
    def train_cameras(self) -> list[Camera]:
        """The training cameras at frame 0, ordered by camera id."""
        return [view.camera for view in self.views_at(0, "train")]

    @property
    def test_cameras(self) -> list[Camera]:
        """The held-out test cameras at frame 0, ordered by camera id."""
        return [view.camera for view in self.views_at(0, "test")]

    def rescaled(self, downscale: int) -> Scene:
        """The same scene at another downscale factor, sharing this scene's image cache."""
        downscale = require_int("downscale", downscale, minimum=1)
        return replace(
            self,
            train_views=scale_views(self.full_train_views, downscale),
            test_views=scale_views(self.full_test_views, downscale),
            downscale=downscale,
        )


def map_cameras(views: list[View], change: Callable[[Camera], Camera]) -> list[View]:
    """Views with each camera replaced by `change(camera)`; shared cameras stay shared."""
    changed: dict[int, Camera] = {}
    result = []
    for view in views:
        key = id(view.camera)
        if key not in changed:
            changed[key] = change(view.camera)
        result.append(replace(view, camera=changed[key]))
    return result


def _require_visible_size(root: Path, views: list[View], downscale: int) -> None:
    """One line when `downscale` leaves a view's image under MIN_IMAGE_SIDE pixels a side."""
    camera = min((view.camera for view in views), key=lambda cam: min(cam.width, cam.height))
    scaled = camera.scaled(downscale)
    if min(scaled.width, scaled.height) < MIN_IMAGE_SIDE:
        raise InputError(
            f"{root}: downscale {downscale} turns its {camera.width}x{camera.height} images into "
            f"{scaled.width}x{scaled.height}; expected at least {MIN_IMAGE_SIDE} pixels a side "
            "(a smaller downscale)"
        )


def scale_views(views: list[View], downscale: int) -> list[View]:
    """Views with cameras downscaled by `downscale`."""
    return map_cameras(views, lambda camera: camera.scaled(downscale))


def split_views(
    views: list[View], test_ids: set[int], source: Path
) -> tuple[list[View], list[View]]:
    """(train, test) views by camera id, ordered by (frame, camera); no train camera is refused."""
    views = sorted(views, key=lambda view: (view.frame, view.camera.camera_id))
    train_views = [view for view in views if view.camera.camera_id not in test_ids]
    test_views = [view for view in views if view.camera.camera_id in test_ids]
    if not train_views:
        raise InputError(
            f"{source}: no training cameras left after holding out {sorted(test_ids)}; hold out "
            f"fewer (or none), e.g. {test_cameras_setting([])}"
        )
    return train_views, test_views


def hold_out(
    views: list[View], ids: Iterable[int], known: set[int], root: Path, source: str, where: str
) -> tuple[list[View], list[View]]:
    """`split_views` holding out `ids` (named by `source`), refusing ids not in `known`; the
    error suggests those it has, when that leaves a camera to train on, else none."""
    missing = [camera_id for camera_id in ids if camera_id not in known]
    if missing:
        kept = [camera_id for camera_id in ids if camera_id in known]
        instead = test_cameras_setting(kept if len(kept) < len(known) else [])
        raise InputError(f"{source}: cameras {missing} are not in {where}, e.g. {instead}")
    return split_views(views, set(ids), root)


def scene_extent(cameras: list[Camera], points: PointCloud) -> float:
    """1.1 × the radius of the camera centres (the 3DGS rule), or of the point cloud when the
    cameras share one position: a zero extent would freeze means and prune every Gaussian."""
    centers = np.stack([camera.center.double().numpy() for camera in cameras])
    radius = _radius(centers)
    cloud = _radius(points.xyz.double().numpy())
    if radius <= SAME_POSITION * cloud:
        radius = cloud
    return max(radius, 1e-6) * 1.1


def _radius(positions: np.ndarray) -> float:
    """The largest distance of a position [N,3] from their mean."""
    return float(np.linalg.norm(positions - positions.mean(axis=0), axis=1).max())


def _require_points_in_view(
    root: Path, cameras: list[Camera], points: PointCloud, near: float
) -> None:
    """One line unless a point lies in front of a training camera and inside its image (else
    training learns a black scene); the usual cause is camera→world or OpenGL poses."""
    xyz = points.xyz.to(torch.float32)
    for camera in cameras:  # a usable scene ends at its first camera
        if bool(camera.project(xyz, min_depth=near)[1].any()):
            return
    raise InputError(
        f"{root}: none of the point cloud's {len(xyz)} points is in front of a training camera "
        "and inside its image; expected world→camera poses in OpenCV axes (x right, y down, z "
        "forward): camera→world poses, or OpenGL axes (y up, z backward), put the scene "
        "behind the cameras"
    )


def assemble_scene(
    root: Path,
    format: str,
    train_views: list[View],
    test_views: list[View],
    num_frames: int,
    points: PointCloud,
    options: LoaderOptions,
    content: dict[str, Any],
) -> Scene:
    """A Scene of full-resolution views (extent, near planes from it, views scaled) whose
    fingerprint covers `content` (the input files' hashes) and the content options."""
    downscale = options.downscale
    _require_visible_size(root, [*train_views, *test_views], downscale)
    train_cameras = {id(view.camera): view.camera for view in train_views}
    extent = scene_extent(list(train_cameras.values()), points)
    near = near_plane_for(extent)
    _require_points_in_view(root, list(train_cameras.values()), points, near)
    train_views, test_views = (
        map_cameras(views, lambda camera: replace(camera, near=near))
        for views in (train_views, test_views)
    )
    return Scene(
        name=root.name,
        root=root,
        format=format,
        train_views=scale_views(train_views, downscale),
        test_views=scale_views(test_views, downscale),
        num_frames=num_frames,
        points=points,
        effects=declared_effects(root) if options.effects is None else options.effects,
        extent=extent,
        downscale=downscale,
        content_digest=digest({"format": format, "options": options.content_options(), **content}),
        cache=TensorCache(options.cache_mb),
        full_train_views=train_views,
        full_test_views=test_views,
    )
