"""`load_scene`: detect a scene folder's layout and load it with validated options."""

from __future__ import annotations

import shlex
from collections.abc import Iterable
from pathlib import Path

from relaygs.data.multiview import camera_folders, load_multiview
from relaygs.data.options import (
    DEFAULT_CACHE_MB,
    DEFAULT_MAX_POINTS,
    OPTION_PREFIX,
    make_options,
)
from relaygs.data.panoptic import TRAIN_META, load_panoptic
from relaygs.data.scene import Scene
from relaygs.data.video_frames import VIDEO_SUFFIXES
from relaygs.errors import InputError
from relaygs.paths import require_folder
from relaygs.shell import python_command


def detect_format(root: Path) -> str:
    """'panoptic' when train_meta.json exists (a folder of that name is refused when it is
    read), 'multiview' when camXX/ folders exist; a folder it cannot read is one line."""
    try:
        return _layout_of(root)
    except PermissionError as error:
        raise InputError(f"{root}: cannot read the scene folder ({error.strerror})") from None


def _layout_of(root: Path) -> str:
    if (root / TRAIN_META).exists():
        return "panoptic"
    if camera_folders(root):
        return "multiview"
    hint = ""
    if any(path.suffix.lower() in VIDEO_SUFFIXES for path in root.iterdir()):
        frames = f"{python_command()} -m relaygs.frames {shlex.quote(str(root))} SCENE_DIR"
        hint = f"; for one video per camera, run {frames}"
    raise InputError(
        f"{root}: unknown scene layout; expected {TRAIN_META} (PanopticSports layout) or "
        f"camXX/ frame folders with a COLMAP model (multi-view layout){hint}"
    )


def load_scene(
    path: str | Path,
    *,
    downscale: int = 1,
    max_points: int = DEFAULT_MAX_POINTS,
    cache_mb: float = DEFAULT_CACHE_MB,
    test_cameras: Iterable[int] | None = None,
    effects: Iterable[str] | None = None,
    option_prefix: str = OPTION_PREFIX,
) -> Scene:
    """Load the scene folder at `path` in whichever supported layout it uses.

    downscale: integer factor for half/quarter resolution; max_points: voxel-downsampling budget
    of the initial cloud; cache_mb: in-memory image cache budget; test_cameras: held-out camera
    ids (default: test_meta.json; multi-view: scene.json's, else 0/10/20/30); effects: override
    scene.json; option_prefix: how errors name these options (the app's `scene.loader.`).
    """
    root = require_folder(Path(path).expanduser().absolute(), "scene folder")
    options = make_options(
        downscale=downscale,
        max_points=max_points,
        cache_mb=cache_mb,
        test_cameras=test_cameras,
        effects=effects,
        prefix=option_prefix,
    )
    if detect_format(root) == "panoptic":
        return load_panoptic(root, options)
    return load_multiview(root, options)
