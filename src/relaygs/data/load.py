"""`load_scene`: detect a scene folder's layout and load it with validated options."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

from relaygs.data.multiview import camera_folders, load_multiview
from relaygs.data.options import OPTION_PREFIX, make_options
from relaygs.data.panoptic import TRAIN_META, load_panoptic
from relaygs.data.scene import Scene
from relaygs.data.video_frames import VIDEO_SUFFIXES
from relaygs.errors import InputError
from relaygs.paths import require_folder
from relaygs.shell import python_command


def detect_format(root: Path) -> str:
    """'panoptic' (train_meta.json) or 'multiview' (camXX/ folders); else one line."""
    try:
        if (root / TRAIN_META).exists():
            return "panoptic"
        if camera_folders(root):
            return "multiview"
        videos = any(path.suffix.lower() in VIDEO_SUFFIXES for path in root.iterdir())
    except PermissionError as error:
        raise InputError(f"{root}: cannot read the scene folder ({error.strerror})") from None
    hint = ""
    if videos:
        frames = f"{python_command()} -m relaygs.frames {shlex.quote(str(root))} SCENE_DIR"
        hint = f"; for one video per camera, run {frames}"
    raise InputError(
        f"{root}: unknown scene layout; expected {TRAIN_META} (PanopticSports layout) or "
        f"camXX/ frame folders with a COLMAP model (multi-view layout){hint}"
    )


def load_scene(path: str | Path, *, option_prefix: str = OPTION_PREFIX, **options: Any) -> Scene:
    """Load the scene folder at `path` (Panoptic or multi-view layout) with `make_options`'
    options; errors name them `option_prefix` + name (the app's `scene.loader.`)."""
    root = require_folder(Path(path).expanduser().absolute(), "scene folder")
    checked = make_options(prefix=option_prefix, **options)
    if detect_format(root) == "panoptic":
        return load_panoptic(root, checked)
    return load_multiview(root, checked)
