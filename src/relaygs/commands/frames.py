"""`python -m relaygs.frames VIDEOS_DIR OUT_DIR`: turn one video per camera into the multi-view
layout's camXX/frame_XXXXX images, ready for COLMAP and `relaygs.run scene.path=OUT_DIR`."""

from __future__ import annotations

import argparse
import os
import shlex
import time
from collections.abc import Sequence

from relaygs.cli import OneLineErrorParser, int_at_least, one_line_failures, path_argument
from relaygs.data.video_frames import (
    COLMAP_LIST,
    FRAME_FORMATS,
    ExtractedScene,
    FrameSelection,
    camera_videos,
    extract_frames,
    rates_agree,
)
from relaygs.shell import path_override, python_command


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the frames command."""
    parser = OneLineErrorParser(prog="python -m relaygs.frames", description=__doc__)
    parser.add_argument(
        "videos_dir", type=path_argument, help="folder holding one video per camera"
    )
    parser.add_argument("out_dir", type=path_argument, help="new (or empty) scene folder to write")
    parser.add_argument(
        "--start",
        type=int_at_least(0),
        default=0,
        metavar="F",
        help="first source frame (default 0)",
    )
    parser.add_argument(
        "--stride",
        type=int_at_least(1),
        default=1,
        metavar="N",
        help="keep every N-th frame (default 1)",
    )
    parser.add_argument(
        "--frames", type=int_at_least(1), metavar="T", help="keep at most T frames (default: all)"
    )
    parser.add_argument(
        "--format", choices=FRAME_FORMATS, default="jpg", help="image format (default jpg)"
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; 0 on success, 1 with one line on stderr on bad input or a full disk."""
    args = build_parser().parse_args(argv)
    # FFmpeg's own log lines ("moov atom not found") would come before ours, which names the file
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    return one_line_failures(lambda: _extract(args), where=f"frames into {args.out_dir}")


def _extract(args: argparse.Namespace) -> None:
    started = time.perf_counter()
    videos = camera_videos(args.videos_dir)
    selection = FrameSelection(args.start, args.stride, args.frames)
    scene = extract_frames(videos, args.out_dir, selection, args.format)
    print(describe(scene, time.perf_counter() - started))


def describe(scene: ExtractedScene, seconds: float) -> str:
    """What was written, notes on the videos, and the commands that pose and train the scene."""
    rate = f" at {scene.fps:.4g} fps" if scene.fps is not None else ""
    lines = [
        f"wrote {scene.frames} frame(s){rate} of {len(scene.cameras)} camera(s) into "
        f"{scene.folder} in {seconds:.1f} s"
    ]
    lines += [f"  {name}  {camera.video}" for name, camera in scene.cameras.items()]
    lines += _notes(scene)
    out = shlex.quote(str(scene.folder))
    lines += [
        f"next, pose the cameras with COLMAP from their first frames ({COLMAP_LIST}):",
        f"  colmap feature_extractor --database_path {out}/colmap.db --image_path {out} "
        f"--image_list_path {out}/{COLMAP_LIST} --ImageReader.camera_model PINHOLE",
        f"  colmap exhaustive_matcher --database_path {out}/colmap.db",
        f"  mkdir -p {out}/sparse && colmap mapper --database_path {out}/colmap.db "
        f"--image_path {out} --output_path {out}/sparse",
        f"then train: {python_command()} -m relaygs.run "
        f"{path_override('scene.path', scene.folder)}",
    ]
    return "\n".join(lines)


def _notes(scene: ExtractedScene) -> list[str]:
    """Notes: killed runs' staging removed, short or damaged videos, differing frame rates."""
    cameras = scene.cameras.items()
    notes = [
        f"note: removed {folder}, left unfinished by a run that was killed"
        for folder in scene.cleared
    ]
    short = [name for name, camera in cameras if camera.ran_out and camera.written == scene.frames]
    if short:
        kept = {name: max(camera.written, camera.available or 0) for name, camera in cameras}
        longer = [name for name in kept if name not in short and kept[name] > scene.frames]
        if longer:
            notes.append(
                f"note: every camera keeps {scene.frames} frame(s), all that {', '.join(short)} "
                f"gave; {', '.join(longer)} had more"
            )
    for name, camera in cameras:
        if camera.ran_out and camera.stated is not None and camera.decoded < camera.stated:
            notes.append(
                f"note: {name}'s {camera.video.name} decoded {camera.decoded} of the "
                f"{camera.stated} frames it states: is it damaged or cut short?"
            )
    rates = [camera.rate for _, camera in cameras]
    if all(rate is not None for rate in rates) and not rates_agree(rates):
        listed = ", ".join(f"{name} {camera.rate:.4g}" for name, camera in cameras)
        notes.append(
            f"note: the videos' frame rates differ ({listed} fps), so frame n of each camera "
            "may not show one moment: convert them to one rate first"
        )
    return notes
