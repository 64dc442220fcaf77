"""One video per camera → the multi-view layout's camXX/frame_XXXXX images (docs/scenes.md),
every camera cut to the frames the shortest video gives, plus a COLMAP list of first frames."""

from __future__ import annotations

import glob
import json
import os
import re
import shutil
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from relaygs.data.multiview import CAMERA_FOLDER
from relaygs.data.staging import process_alive, staging_prefix
from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder, require_folder
from relaygs.progress import progress_bar
from relaygs.shell import path_override, python_command

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")
FRAME_FORMATS = ("jpg", "png")
JPEG_QUALITY = 95
COLMAP_LIST = "colmap_images.txt"
SOURCES_JSON = "frames.json"
MIN_CAMERAS = 2  # one view cannot be posed by COLMAP nor split into train and test cameras
RATE_TOLERANCE = 1e-3  # frame rates this close (relative) are one rate (29.97 vs 30 are not)


@dataclass(frozen=True)
class FrameSelection:
    """Which source frames to keep: `start`, then every `stride`-th, at most `count` (None: all)."""

    start: int = 0
    stride: int = 1
    count: int | None = None

    def keeps(self, index: int) -> bool:
        """Whether source frame `index` is one to write."""
        return index >= self.start and (index - self.start) % self.stride == 0

    def done(self, written: int) -> bool:
        """Whether `written` frames are all that was asked for."""
        return self.count is not None and written >= self.count

    def kept_of(self, frames: int) -> int:
        """How many frames the selection keeps of a video of `frames` frames."""
        kept = max(0, -(-(frames - self.start) // self.stride))
        return kept if self.count is None else min(kept, self.count)


@dataclass(frozen=True)
class CameraFrames:
    """What one camera's video gave; `stated`, `rate` and `available` (what the selection keeps
    of the stated count) are None when the container states none."""

    video: Path
    written: int
    decoded: int
    stated: int | None
    rate: float | None
    ran_out: bool
    available: int | None = None


@dataclass(frozen=True)
class ExtractedScene:
    """What `extract_frames` wrote; `fps` is None unless the videos state one and the same, and
    `cleared` lists the staging folders of killed runs it removed."""

    folder: Path
    cameras: dict[str, CameraFrames]
    frames: int
    fps: float | None
    cleared: tuple[Path, ...] = ()


def camera_videos(folder: Path) -> list[Path]:
    """Video files in `folder` in natural order (cam2 before cam10), hidden files left out."""
    folder = require_folder(Path(folder).expanduser().absolute(), "video folder")
    try:
        entries = list(folder.iterdir())
    except OSError as error:
        raise InputError(f"{folder}: cannot list it ({error.strerror})") from None
    videos = [path for path in entries if path.suffix.lower() in VIDEO_SUFFIXES]
    videos = [path for path in videos if path.is_file() and not path.name.startswith(".")]
    if len(videos) < MIN_CAMERAS:
        scene = any(CAMERA_FOLDER.match(path.name) and path.is_dir() for path in entries)
        hint = (
            f"; its camXX folders make it a scene: {python_command()} -m relaygs.run "
            f"{path_override('scene.path', folder)}"
        )
        raise InputError(
            f"{folder}: expected a video per camera ({', '.join(VIDEO_SUFFIXES)}), at least "
            f"{MIN_CAMERAS}, found {len(videos)}{hint if scene else ''}"
        )
    return sorted(videos, key=_natural_key)


def extract_frames(
    videos: list[Path],
    out_dir: Path,
    selection: FrameSelection = FrameSelection(),
    image_format: str = "jpg",
    progress: bool = True,
) -> ExtractedScene:
    """Write `videos[i]`'s selected frames as `out_dir`/cam<i>/frame_<n>.<format> via a hidden
    sibling folder renamed in at the end, so a failure leaves no partial scene."""
    out = _empty_target(Path(out_dir).expanduser().resolve())
    sources = {f"cam{index:02d}": video for index, video in enumerate(videos)}
    stated = {name: _stated_count(video) for name, video in sources.items()}
    cleared = _clear_killed_staging(out)
    staging = out.parent / f"{staging_prefix(out)}{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        cameras = _write_cameras(sources, stated, staging, selection, image_format, progress)
        frames = min(camera.written for camera in cameras.values())
        for name in cameras:
            _drop_frames_from(staging / name, frames)
        fps = _kept_rate([camera.rate for camera in cameras.values()], selection.stride)
        # where each camera's frames came from, and the list of first frames COLMAP poses
        listing = {"sources": {name: str(video) for name, video in sources.items()}}
        listing.update(frames=frames, start=selection.start, stride=selection.stride, fps=fps)
        (staging / SOURCES_JSON).write_text(json.dumps(listing, indent=2) + "\n", encoding="utf-8")
        first = [f"{name}/frame_00000.{image_format}" for name in sources]
        (staging / COLMAP_LIST).write_text("\n".join(first) + "\n", encoding="utf-8")
    except BaseException:  # a failure or Ctrl-C: no partial scene stays
        shutil.rmtree(staging, ignore_errors=True)
        raise
    _publish(staging, out)
    return ExtractedScene(out, cameras, frames, fps, cleared)


def _clear_killed_staging(out: Path) -> tuple[Path, ...]:
    """Remove `out`'s staging folders whose process is gone and that hold no listing (a finished
    one, whose rename failed, holds the frames an earlier error named)."""
    prefix = staging_prefix(out)
    cleared = []
    for folder in sorted(out.parent.glob(f"{glob.escape(prefix)}*")):
        pid = folder.name.removeprefix(prefix)
        if not pid.isdigit() or process_alive(int(pid)) or (folder / SOURCES_JSON).exists():
            continue
        shutil.rmtree(folder, ignore_errors=True)
        cleared.append(folder)
    return tuple(cleared)


def _natural_key(path: Path) -> list[object]:
    """Sort key that orders the digit runs of a name by value (odd positions of the split)."""
    parts = re.split(r"(\d+)", path.name)
    return [int(part) if index % 2 else part.lower() for index, part in enumerate(parts)]


def _empty_target(out: Path) -> Path:
    """`out` if it is a new or empty folder that can be made and written; else one line."""
    if out.is_file():
        raise InputError(f"{out} is a file: expected a new or empty folder for the frames")
    if out.is_dir() and any(out.iterdir()):
        raise InputError(f"refusing to write frames into {out}: it exists and is not empty")
    return require_creatable_folder(out, "frames folder")


def _stated_count(video: Path) -> int | None:
    """`video`'s stated frame count (or None); a non-video is refused before any decoding."""
    capture = cv2.VideoCapture(str(video))
    try:
        if not capture.isOpened():
            raise InputError(f"{video}: cannot open it as a video")
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
    finally:
        capture.release()
    return int(count) if count > 0 else None


def _write_cameras(
    sources: dict[str, Path],
    stated: dict[str, int | None],
    staging: Path,
    selection: FrameSelection,
    image_format: str,
    progress: bool,
) -> dict[str, CameraFrames]:
    """Write every camera's frames, shortest stated video first, each stopping at the fewest
    frames a camera before it gave (the rest would be dropped)."""
    order = sorted(sources, key=lambda name: (stated[name] is None, stated[name] or 0, name))
    total = None if selection.count is None else selection.count * len(sources)
    bar = progress_bar(total=total, desc="frames", unit="frame", disable=not progress, leave=False)
    cameras: dict[str, CameraFrames] = {}
    with bar:
        for name in order:
            fewest = min((camera.written for camera in cameras.values()), default=None)
            limit = selection if fewest is None else replace(selection, count=fewest)
            camera = _write_camera(
                sources[name], staging / name, limit, image_format, bar, stated[name]
            )
            count = stated[name]
            available = None if count is None else selection.kept_of(count)
            cameras[name] = replace(camera, available=available)
    return {name: cameras[name] for name in sources}


def _write_camera(
    video: Path,
    folder: Path,
    selection: FrameSelection,
    image_format: str,
    bar: tqdm,
    stated: int | None,
) -> CameraFrames:
    """Decode `video` and write its selected frames into `folder`, counting them on `bar`."""
    folder.mkdir()
    capture = cv2.VideoCapture(str(video))
    written = decoded = 0
    try:
        rate = capture.get(cv2.CAP_PROP_FPS)
        for index, image in enumerate(decoded_frames(capture)):
            decoded = index + 1
            if selection.keeps(index):
                _write_image(folder / f"frame_{written:05d}.{image_format}", image)
                written += 1
                bar.update()
                if selection.done(written):
                    break
    finally:
        capture.release()
    if written == 0:
        raise InputError(
            f"{video}: no frame to write (decoded {decoded}, none at or after frame "
            f"{selection.start})"
        )
    ran_out = not selection.done(written)
    return CameraFrames(video, written, decoded, stated, rate if rate > 0 else None, ran_out)


def decoded_frames(capture: cv2.VideoCapture) -> Iterator[np.ndarray]:
    """The video's frames in order until the decoder has no more."""
    while True:
        ok, image = capture.read()
        if not ok:
            return
        yield image


def _write_image(path: Path, image: np.ndarray) -> None:
    """Encode one BGR frame to `path` (JPEG at JPEG_QUALITY, or PNG)."""
    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if path.suffix == ".jpg" else []
    path.write_bytes(cv2.imencode(path.suffix, image, params)[1].tobytes())


def _drop_frames_from(folder: Path, count: int) -> None:
    """Remove a camera's frames numbered `count` and above (beyond the shortest video)."""
    for path in folder.iterdir():
        if int(path.stem.removeprefix("frame_")) >= count:
            path.unlink()


def _kept_rate(rates: list[float | None], stride: int) -> float | None:
    """The videos' frame rate over the stride, or None unless they all state one and the same."""
    known = [rate for rate in rates if rate is not None]
    if len(known) < len(rates) or not rates_agree(known):
        return None
    return known[0] / stride


def rates_agree(rates: list[float]) -> bool:
    """Whether frame rates are one rate, within a relative RATE_TOLERANCE."""
    return max(rates) - min(rates) <= RATE_TOLERANCE * max(rates)


def _publish(staging: Path, out: Path) -> None:
    """Rename the staging folder to `out`; on failure the error names where the frames stay."""
    try:
        if out.exists():
            out.rmdir()
        os.replace(staging, out)
    except OSError as error:
        raise InputError(
            f"cannot move the frames into {out} ({error.strerror}); they are in {staging}"
        ) from None
