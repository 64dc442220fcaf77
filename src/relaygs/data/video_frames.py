"""Per-camera videos → the multi-view layout's camXX/frame_XXXXX images, frame-aligned.

A synchronised capture often arrives as one video per camera. This writes the frames the
multi-view loader reads (docs/scenes.md): the videos in natural name order become cam00,
cam01, …; every camera gets the same frame numbers (the shortest video decides how many), and
`colmap_images.txt` lists each camera's first frame for posing the rig with COLMAP.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder, require_folder
from relaygs.progress import progress_bar

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")
FRAME_FORMATS = ("jpg", "png")
JPEG_QUALITY = 95
COLMAP_LIST = "colmap_images.txt"
SOURCES_JSON = "frames.json"


@dataclass(frozen=True)
class FrameSelection:
    """Which source frames to keep: `start`, then every `stride`-th, at most `count` (None: all)."""

    start: int = 0
    stride: int = 1
    count: int | None = None

    def __post_init__(self) -> None:
        """Refuse a negative start, a stride below 1 or a count below 1 in one line."""
        if self.start < 0 or self.stride < 1 or (self.count is not None and self.count < 1):
            raise InputError(
                "frame selection: expected start >= 0, stride >= 1 and count >= 1, got "
                f"start {self.start}, stride {self.stride}, count {self.count}"
            )

    def keeps(self, index: int) -> bool:
        """Whether source frame `index` is one to write."""
        return index >= self.start and (index - self.start) % self.stride == 0

    def done(self, written: int) -> bool:
        """Whether `written` frames are all that was asked for."""
        return self.count is not None and written >= self.count


@dataclass(frozen=True)
class ExtractedScene:
    """What `extract_frames` wrote: the folder, the camera folders' sources, the common frame
    count, each video's number of selected frames, and the frame rate the frames keep."""

    folder: Path
    sources: dict[str, Path]
    frames: int
    selected: dict[str, int]
    fps: float | None


def camera_videos(folder: Path) -> list[Path]:
    """The video files directly in `folder`, in natural name order (cam2 before cam10)."""
    folder = require_folder(Path(folder).expanduser().absolute(), "video folder")
    videos = [
        path
        for path in folder.iterdir()
        if path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES
    ]
    if not videos:
        raise InputError(f"{folder}: no videos ({', '.join(VIDEO_SUFFIXES)}) in it")
    return sorted(videos, key=_natural_key)


def extract_frames(
    videos: list[Path],
    out_dir: Path,
    selection: FrameSelection = FrameSelection(),
    image_format: str = "jpg",
    progress: bool = True,
) -> ExtractedScene:
    """Write `videos[i]`'s selected frames as `out_dir`/cam<i>/frame_<n>.<format>, n from 0,
    each camera cut to the shortest one's count. `out_dir` must be new or empty; the frames go
    into a sibling folder that is renamed in at the end, so a failure leaves nothing behind."""
    if image_format not in FRAME_FORMATS:
        raise InputError(f"frame format: expected one of {FRAME_FORMATS}, got {image_format!r}")
    out = _empty_target(Path(out_dir).expanduser().absolute())
    staging = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        sources = {f"cam{index:02d}": video for index, video in enumerate(videos)}
        selected, rates = {}, []
        total = None if selection.count is None else selection.count * len(videos)
        bar = progress_bar(
            total=total, desc="frames", unit="frame", disable=not progress, leave=False
        )
        with bar:
            for name, video in sources.items():
                written, rate = _write_camera(video, staging / name, selection, image_format, bar)
                selected[name] = written
                rates.append(rate)
        frames = min(selected.values())
        for name in sources:
            _drop_frames_from(staging / name, frames)
        fps = _kept_rate(rates, selection.stride)
        _write_listing(staging, sources, frames, selection, fps, image_format)
        if out.exists():
            out.rmdir()  # empty, checked above
        os.replace(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return ExtractedScene(out, sources, frames, selected, fps)


def _natural_key(path: Path) -> list[object]:
    """Sort key that orders the digit runs of a name by value."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


def _empty_target(out: Path) -> Path:
    """`out` if it is a new or empty folder that can be made and written; else one line."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"refusing to write frames into {out}: it exists and is not empty")
    return require_creatable_folder(out, "frames folder")


def _write_camera(
    video: Path, folder: Path, selection: FrameSelection, image_format: str, bar: tqdm
) -> tuple[int, float | None]:
    """Decode `video` and write its selected frames into `folder`, counting them on `bar`;
    (frames written, the video's frame rate or None)."""
    folder.mkdir()
    capture = cv2.VideoCapture(str(video))
    try:
        if not capture.isOpened():
            raise InputError(f"{video}: cannot open it as a video")
        rate = capture.get(cv2.CAP_PROP_FPS)
        written = 0
        for index, image in enumerate(_decoded(capture)):
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
            f"{video}: no frame to write (decoded none at or after frame {selection.start})"
        )
    return written, rate if rate > 0 else None


def _decoded(capture: cv2.VideoCapture) -> Iterator[np.ndarray]:
    """The video's frames in order until the decoder has no more."""
    while True:
        ok, image = capture.read()
        if not ok:
            return
        yield image


def _write_image(path: Path, image: np.ndarray) -> None:
    """Encode one BGR frame to `path` (JPEG at JPEG_QUALITY, or PNG)."""
    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if path.suffix == ".jpg" else []
    ok, data = cv2.imencode(path.suffix, image, params)
    if not ok:
        raise InputError(f"cannot encode a frame as {path.suffix}: {path}")
    path.write_bytes(data.tobytes())


def _drop_frames_from(folder: Path, count: int) -> None:
    """Remove a camera's frames numbered `count` and above (beyond the shortest video)."""
    for path in folder.iterdir():
        if int(path.stem.removeprefix("frame_")) >= count:
            path.unlink()


def _kept_rate(rates: list[float | None], stride: int) -> float | None:
    """The frame rate the written frames keep (the videos' rate over the stride), or None when
    the videos do not all state one and the same."""
    if any(rate is None for rate in rates) or max(rates) - min(rates) > 1e-3 * max(rates):
        return None
    return rates[0] / stride


def _write_listing(
    folder: Path,
    sources: dict[str, Path],
    frames: int,
    selection: FrameSelection,
    fps: float | None,
    image_format: str,
) -> None:
    """`frames.json` (where each camera's frames came from) and the COLMAP image list."""
    listing = {
        "sources": {name: str(video) for name, video in sources.items()},
        "frames": frames,
        "start": selection.start,
        "stride": selection.stride,
        "fps": fps,
    }
    (folder / SOURCES_JSON).write_text(json.dumps(listing, indent=2) + "\n", encoding="utf-8")
    first = [f"{name}/frame_00000.{image_format}" for name in sources]
    (folder / COLMAP_LIST).write_text("\n".join(first) + "\n", encoding="utf-8")
