"""A stored model's renders over time (`python -m relaygs.artifacts render`): a PNG per frame and
an MP4 per camera, other models, the truth and error images beside, or a video along an orbit
that the scene's cameras place around its centre."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from relaygs.camera_path import path_cameras
from relaygs.data import Scene, View
from relaygs.data.scene import frame_time
from relaygs.error_map import error_image
from relaygs.errors import InputError, RelayGSError
from relaygs.progress import progress_bar
from relaygs.train.evaluate import require_its_scene
from relaygs.train.model_render import ModelRenderer
from relaygs.train.scene_model import SceneModel

VIDEO_CODEC = "mp4v"  # MPEG-4 part 2: the encoder every OpenCV wheel carries
PATH_NAME = "path"  # a camera path's PNG folder and video are <out>/path and <out>/path.mp4
FRAME_GLOB = "[0-9]" * 6 + ".png"  # the frames a render writes: <frame or view>.png


@dataclass(frozen=True)
class RenderSettings:
    """Which cameras (None: the test cameras), every `frame_stride`-th frame, the truth and
    error images beside or not, and the videos' frame rate (None: no video)."""

    camera_ids: tuple[int, ...] | None = None
    frame_stride: int = 1
    with_truth: bool = False
    fps: float | None = 15.0
    with_error: bool = False

    def __post_init__(self) -> None:
        if self.frame_stride < 1:
            raise InputError(f"render frame_stride: expected an int >= 1, got {self.frame_stride}")
        _require_fps(self.fps)


@dataclass(frozen=True)
class PathSettings:
    """`views` poses along the orbit of the chosen cameras (None: the train cameras), the model
    at `frame` throughout or (None) at times from the first frame to the last, and a frame rate."""

    views: int
    camera_ids: tuple[int, ...] | None = None
    frame: int | None = None
    fps: float | None = 15.0

    def __post_init__(self) -> None:
        if self.views < 1:
            raise InputError(f"render path: expected at least 1 view, got {self.views}")
        _require_fps(self.fps)


def _require_fps(fps: float | None) -> None:
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"render fps: expected a positive number, got {fps}")


@dataclass(frozen=True)
class CameraRenders:
    """What was written for one camera (None: a camera path): frames, PNG folder, video."""

    camera_id: int | None
    frames: list[int]
    folder: Path
    video: Path | None


def chosen_cameras(scene: Scene, camera_ids: Sequence[int] | None) -> list[int]:
    """`camera_ids` checked against the scene's cameras, or (None) its test cameras, else all."""
    available = sorted({view.camera.camera_id for view in scene.train_views + scene.test_views})
    if camera_ids is None:
        tests = sorted({view.camera.camera_id for view in scene.test_views})
        return tests or available
    unknown = [camera for camera in camera_ids if camera not in available]
    if unknown:
        raise InputError(f"camera {unknown[0]} is not in {scene.root}: its cameras are {available}")
    return list(dict.fromkeys(camera_ids))


def write_renders(
    scene: Scene,
    model: SceneModel,
    out: Path,
    settings: RenderSettings,
    progress: bool = True,
    beside: Sequence[SceneModel] = (),
) -> list[CameraRenders]:
    """Render `model` (and the models `beside` it) into `out`/cam<ID>/<frame>.png and, with a
    frame rate, `out`/cam<ID>.mp4 (moved in only when complete)."""
    renderers = _renderers(scene, [model, *beside])
    cameras = chosen_cameras(scene, settings.camera_ids)
    sinks = {
        camera: _CameraSink(out, f"cam{camera:02d}", settings.fps, camera) for camera in cameras
    }
    frames = range(0, scene.num_frames, settings.frame_stride)
    with _written_whole(out, list(sinks.values())):
        for frame in progress_bar(
            frames, desc="render", unit="frame", disable=not progress, leave=False
        ):
            views = [v for v in scene.views_at(frame, "all") if v.camera.camera_id in sinks]
            if not views:
                continue
            cameras_now = [view.camera for view in views]
            per_model = [r.render(cameras_now, views[0].time) for r in renderers]
            for index, view in enumerate(views):
                renders = [images[index].cpu() for images in per_model]
                sinks[view.camera.camera_id].add(frame, _picture(renders, view, scene, settings))
    return [sink.result() for sink in sinks.values()]


def _renderers(scene: Scene, models: Sequence[SceneModel]) -> list[ModelRenderer]:
    for model in models:
        require_its_scene(model, scene)
    return [ModelRenderer(model) for model in models]


def _picture(renders: list[Tensor], view: View, scene: Scene, settings: RenderSettings) -> Tensor:
    """The models' renders, then the truth and their error images where asked, side by side."""
    parts = list(renders)
    if settings.with_truth or settings.with_error:
        truth = scene.image(view)
        parts += [truth] if settings.with_truth else []
        parts += [error_image(render, truth) for render in renders] if settings.with_error else []
    return torch.cat(parts, dim=1)


def write_path_render(
    scene: Scene,
    model: SceneModel,
    out: Path,
    settings: PathSettings,
    progress: bool = True,
    beside: Sequence[SceneModel] = (),
) -> CameraRenders:
    """Render `model` (and the models `beside` it) along the cameras' orbit into
    `out`/path/<view>.png and, with a frame rate, `out`/path.mp4."""
    renderers = _renderers(scene, [model, *beside])
    if settings.frame is not None and not 0 <= settings.frame < scene.num_frames:
        raise InputError(
            f"render path frame {settings.frame} is not in {scene.root}: its frames are "
            f"0..{scene.num_frames - 1}"
        )
    ids = settings.camera_ids or [camera.camera_id for camera in scene.train_cameras]
    at_start = {view.camera.camera_id: view.camera for view in scene.views_at(0, "all")}
    chosen = [at_start[camera] for camera in chosen_cameras(scene, ids)]
    centre = scene.points.xyz.median(dim=0).values  # every loader refuses a scene without points
    path = path_cameras(chosen, settings.views, centre)
    if settings.frame is not None:
        times = [frame_time(settings.frame, scene.num_frames)] * settings.views
    else:
        times = [view / max(settings.views - 1, 1) for view in range(settings.views)]
    sink = _CameraSink(out, PATH_NAME, settings.fps)
    with _written_whole(out, [sink]):
        bar = progress_bar(
            range(settings.views), desc="path", unit="view", disable=not progress, leave=False
        )
        for view in bar:
            renders = [r.render([path[view]], times[view])[0].cpu() for r in renderers]
            sink.add(view, torch.cat(renders, dim=1))
    return sink.result()


@contextmanager
def _written_whole(out: Path, sinks: list[_CameraSink]) -> Iterator[None]:
    """Finish the sinks, or remove their unfinished videos; an unwritable path is one line."""
    try:
        yield
        for sink in sinks:
            sink.finish()
    except OSError as error:
        where = error.filename2 or error.filename or out  # filename2: where a move went
        raise InputError(f"cannot write {where}: {error.strerror or error}") from error
    finally:
        for sink in sinks:
            sink.abandon()


def _even_sized(pixels: np.ndarray) -> np.ndarray:
    """The frame with an odd last row or column repeated: the MPEG-4 encoder would drop it."""
    height, width = pixels.shape[:2]
    bottom, right = height % 2, width % 2
    if not (bottom or right):
        return pixels
    return cv2.copyMakeBorder(pixels, 0, bottom, 0, right, cv2.BORDER_REPLICATE)


class _CameraSink:
    """PNG frames and an MP4 of one camera or path, the video built under a temporary name."""

    def __init__(
        self, out: Path, name: str, fps: float | None, camera_id: int | None = None
    ) -> None:
        self.camera_id = camera_id
        self.folder = out / name
        self.video = out / f"{name}.mp4" if fps is not None else None
        self.partial = out / f".{name}.partial.mp4"
        self.fps = fps
        self.frames: list[int] = []
        self._writer: cv2.VideoWriter | None = None

    def add(self, frame: int, image: Tensor) -> None:
        """Write `image` [H,W,3] in [0, 1] as frame `frame` (the first clears earlier frames)."""
        pixels = _to_bgr8(image)
        if not self.frames:
            for earlier in self.folder.glob(FRAME_GLOB):
                earlier.unlink()
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"{frame:06d}.png"  # as FRAME_GLOB
        if not cv2.imwrite(str(path), pixels):
            raise RelayGSError(f"cannot write {path}")
        if self.fps is not None:
            even = _even_sized(pixels)
            self._video_writer(even).write(even)
        self.frames.append(frame)

    def finish(self) -> None:
        """Close the video and move it to its name (every frame has been added)."""
        if self._writer is not None and self.video is not None:
            self._writer.release()
            self._writer = None
            os.replace(self.partial, self.video)

    def abandon(self) -> None:
        """Close and remove a video that was not finished (no-op after `finish`)."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        self.partial.unlink(missing_ok=True)  # also when moving it into place failed

    def result(self) -> CameraRenders:
        """What was written."""
        video = self.video if self.frames else None
        return CameraRenders(self.camera_id, list(self.frames), self.folder, video)

    def _video_writer(self, pixels: np.ndarray) -> cv2.VideoWriter:
        if self._writer is None:
            height, width = pixels.shape[:2]
            fourcc = cv2.VideoWriter_fourcc(*VIDEO_CODEC)
            writer = cv2.VideoWriter(str(self.partial), fourcc, float(self.fps), (width, height))
            if not writer.isOpened():
                raise RelayGSError(
                    f"cannot write {self.video}: this OpenCV has no {VIDEO_CODEC} encoder "
                    "(pass --no-video for PNG frames only)"
                )
            self._writer = writer
        return self._writer


def _to_bgr8(image: Tensor) -> np.ndarray:
    """[H,W,3] float RGB in [0, 1] as contiguous uint8 BGR (NaN and -inf black, +inf white)."""
    clean = torch.nan_to_num(image.detach().float(), nan=0.0, posinf=1.0, neginf=0.0)
    rgb = (clean.clamp(0.0, 1.0) * 255.0).round().to(torch.uint8).numpy()
    return np.ascontiguousarray(rgb[..., ::-1])
