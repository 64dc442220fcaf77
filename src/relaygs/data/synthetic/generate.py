"""`generate`: render a preset into a PanopticSports-layout folder plus scene.json."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from relaygs.data.effects import ALL_EFFECTS, COLOR_INCONSISTENCY, SENSOR_NOISE, parse_effects
from relaygs.data.metafiles import SCENE_JSON
from relaygs.data.options import require_int
from relaygs.data.panoptic import POINTS_FILE, TEST_META, TRAIN_META
from relaygs.data.scene import MIN_IMAGE_SIDE
from relaygs.data.staging import process_alive, staging_prefix
from relaygs.data.synthetic.presets import DURATION_S, PRESETS, Preset
from relaygs.data.synthetic.render import (
    Buffers,
    CameraRays,
    Layer,
    camera_rays,
)
from relaygs.data.synthetic.sensor import (
    NOISE_SIGMA,
    camera_responses,
    noise_generator,
    sensor_image,
)
from relaygs.data.synthetic.world import Primitive, RigCamera, World
from relaygs.errors import InputError
from relaygs.paths import require_creatable_folder
from relaygs.progress import progress_bar

PRESETS_FILE = "relaygs/data/synthetic/presets.py"
GENERATOR = "relaygs.synth"
GENERATOR_VERSION = "1"
GENERATED_ENTRIES = frozenset({"ims", "seg", TRAIN_META, TEST_META, POINTS_FILE, SCENE_JSON})
"""What a generated scene folder holds (regenerating replaces exactly these)."""
MAX_SYNTH_COUNT = 100_000  # most frames, and pixels a side: numpy could not even make more
GENERATED_IMAGE = re.compile(r"\d+/\d{6}\.png")  # what the generator writes in ims/ and seg/
SUPERSAMPLE = 2
POINTS_PER_PIXEL = 0.1  # initial-cloud samples per pixel of each training camera's frame 0 ..
MAX_POINTS = 100_000  # ... capped at this many points in total (the loaders' default budget)
_PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1]


def generate(
    preset: str,
    out_dir: str | Path,
    *,
    frames: int = 64,
    width: int = 160,
    height: int = 90,
    seed: int = 0,
    effects: Iterable[str] | None = None,
    progress: bool = False,
) -> Path:
    """Write `preset` to `out_dir` (Panoptic layout + scene.json) with its default `effects`
    or exactly the given ones; only a generated scene there is replaced."""
    recipe = PRESETS.get(preset)
    if recipe is None:
        raise InputError(f"unknown preset {preset!r}; expected one of: {', '.join(PRESETS)}")
    require_valid_preset(preset, recipe)
    # an image under MIN_IMAGE_SIDE pixels a side is one no loader takes: refused before work
    minimums = {"frames": 1, "width": MIN_IMAGE_SIDE, "height": MIN_IMAGE_SIDE}
    for name, value in (("frames", frames), ("width", width), ("height", height)):
        require_int(name, value, minimum=minimums[name], prefix="", maximum=MAX_SYNTH_COUNT)
    require_int("seed", seed, minimum=0, prefix="")
    declared = declared_effects(recipe, effects)
    times = np.linspace(0.0, DURATION_S, frames) if frames > 1 else np.zeros(1)
    cameras = rig_cameras(recipe, width, height)
    primitives = _primitives(recipe, times, declared, seed)
    world = World(cameras, recipe.test_cameras, primitives, times, width, height)
    out = Path(out_dir).expanduser().absolute()
    staging = _staging_folder(out)
    try:
        _write_scene(world, staging, declared, seed, progress)
        _write_json(staging / SCENE_JSON, _declaration(recipe, world, declared, seed))
        if out.exists():
            shutil.rmtree(out)
        os.replace(staging, out)
    except OSError as error:  # a write that fails on close names no file: name the scene's
        if error.filename is None and error.errno is not None:
            raise OSError(error.errno, error.strerror, str(out)) from error
        raise
    finally:
        if staging.exists():
            shutil.rmtree(staging)
    return out


def require_valid_preset(key: str, recipe: Preset) -> None:
    """Refuse a preset whose name is not its PRESETS key (scene.json and the cache carry it) or
    whose effects are not frozensets of known effect names."""
    where = f"PRESETS[{key!r}]"
    if recipe.name != key:
        raise InputError(
            f"{where}.name ({PRESETS_FILE}) is {recipe.name!r}; expected {key!r}, its PRESETS key"
        )
    for field in ("default_effects", "supported_effects"):
        effects = getattr(recipe, field)
        if not isinstance(effects, frozenset):
            raise InputError(
                f"{where}.{field} ({PRESETS_FILE}): expected a frozenset of effect names, "
                f"got a {type(effects).__name__}"
            )
        unknown = sorted(map(str, effects - ALL_EFFECTS))
        if unknown:
            raise InputError(
                f"{where}.{field} ({PRESETS_FILE}): unknown effect(s) {unknown}; expected "
                f"some of: {', '.join(sorted(ALL_EFFECTS))}"
            )


def rig_cameras(recipe: Preset, width: int, height: int) -> list[RigCamera]:
    """The preset's rig; its test cameras must be distinct indices into it, leaving some."""
    cameras = recipe.rig(width, height)
    count, test = len(cameras), recipe.test_cameras
    fits = 0 < len(set(test)) == len(test) < count
    if not fits or any(not 0 <= index < count for index in test):
        raise InputError(
            f"PRESETS[{recipe.name!r}].test_cameras ({PRESETS_FILE}) {list(test)} must be "
            f"distinct indices into its rig of {count} cameras (0..{count - 1}), at least "
            "one, leaving some to train on"
        )
    return cameras


def _primitives(
    recipe: Preset, times: np.ndarray, effects: frozenset[str], seed: int
) -> list[Primitive]:
    primitives = recipe.build(times, effects, seed)
    if not isinstance(primitives, list) or not all(isinstance(p, Primitive) for p in primitives):
        raise InputError(
            f"PRESETS[{recipe.name!r}].build ({PRESETS_FILE}) returned "
            f"{type(primitives).__name__}; expected a list of Primitive"
        )
    return primitives


def declared_effects(
    recipe: Preset, effects: Iterable[str] | None, source: str = "effects"
) -> frozenset[str]:
    """The preset's default effects for None, else `effects`; each must be supported."""
    if effects is None:
        source = f"PRESETS[{recipe.name!r}].default_effects ({PRESETS_FILE})"
        _require_supported(recipe, recipe.default_effects, source)
        return recipe.default_effects
    declared = parse_effects(effects, source=source)
    _require_supported(recipe, declared, source)
    return declared


def _require_supported(recipe: Preset, effects: frozenset[str], source: str) -> None:
    """Refuse effects the preset cannot simulate (scene.json would declare them unsimulated)."""
    unsupported = sorted(effects - recipe.supported_effects)
    if unsupported:
        raise InputError(
            f"{source}: preset {recipe.name!r} cannot simulate {', '.join(unsupported)}; "
            f"it supports: {', '.join(sorted(recipe.supported_effects))}"
        )


def _staging_folder(out: Path) -> Path:
    """A fresh sibling folder to write into; `out` may only be absent or a scene this generator
    wrote (anything else would be lost), and not a symbolic link."""
    if out.is_symlink():
        raise InputError(f"output path is a symbolic link: {out}; pass the folder it points to")
    if out.exists():
        if not out.is_dir():
            raise InputError(f"output path exists and is not a folder: {out}")
        entries = {entry.name for entry in out.iterdir()}
        if entries and not _is_generated(out):
            raise InputError(f"refusing to overwrite {out}: not empty and not a generated scene")
        foreign = sorted(entries - GENERATED_ENTRIES) + _foreign_image_files(out)
        if foreign:
            shown = foreign if len(foreign) <= 5 else [*foreign[:5], f"... {len(foreign)} in all"]
            raise InputError(
                f"refusing to overwrite {out}: besides a generated scene it holds {shown}; "
                "move them or write the scene elsewhere"
            )
    require_creatable_folder(out.parent, "synthetic scene folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_abandoned_staging(out)
    writer = f"{socket.gethostname()}-{os.getpid()}"  # who writes it: this machine, process
    staging = out.parent / f"{staging_prefix(out)}{writer}"
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir()
    return staging


def remove_abandoned_staging(out: Path, *, any_writer: bool = False) -> None:
    """Delete the staging folders beside `out` of processes of this machine that ended (all of
    them with `any_writer`, when the caller holds the lock every generation of `out` takes)."""
    for staging in out.parent.glob(f"{staging_prefix(out)}*"):
        writer = staging.name[len(staging_prefix(out)) :]
        if staging.is_dir() and (any_writer or _is_gone(writer)):
            shutil.rmtree(staging, ignore_errors=True)


def _is_gone(writer: str) -> bool:
    """Whether the `<host>-<pid>` writer is a process of this machine that has ended."""
    host, _, pid = writer.rpartition("-")
    return host == socket.gethostname() and pid.isdigit() and not process_alive(int(pid))


def _foreign_image_files(scene: Path) -> list[str]:
    """Files under ims/ and seg/ the generator does not write: regenerating would lose them."""
    foreign = []
    for kind in ("ims", "seg"):
        for path in sorted((scene / kind).rglob("*")):
            relative = path.relative_to(scene / kind).as_posix()
            if not path.is_dir() and not GENERATED_IMAGE.fullmatch(relative):
                foreign.append(f"{kind}/{relative}")
    return foreign


def _is_generated(folder: Path) -> bool:
    try:
        declaration = json.loads((folder / SCENE_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(declaration, dict) and declaration.get("generator") == GENERATOR


def _write_json(path: Path, payload: object) -> None:
    path.write_text(json.dumps(payload, indent=1) + "\n", encoding="utf-8")


def _declaration(recipe: Preset, world: World, effects: frozenset[str], seed: int) -> dict:
    gains, offsets = camera_responses(len(world.cameras), seed, COLOR_INCONSISTENCY in effects)
    return {
        "generator": GENERATOR,
        "generator_version": GENERATOR_VERSION,
        "preset": recipe.name,
        "description": recipe.description,
        "frames": len(world.times_s),
        "width": world.width,
        "height": world.height,
        "seed": seed,
        "effects": sorted(effects),
        "num_cameras": len(world.cameras),
        "test_cameras": list(world.test_cameras),
        "duration_s": DURATION_S,
        "supersample": SUPERSAMPLE,
        "noise_sigma": NOISE_SIGMA if SENSOR_NOISE in effects else 0.0,
        "camera_response": {"gains": gains.tolist(), "offsets": offsets.tolist()},
    }


def _write_scene(
    world: World, folder: Path, effects: frozenset[str], seed: int, progress: bool
) -> None:
    """Render every camera and frame into ims/ and seg/, then the meta files and point cloud."""
    num_frames = len(world.times_s)
    static = Layer([primitive for primitive in world.primitives if not primitive.animated])
    dynamic = Layer([primitive for primitive in world.primitives if primitive.animated])
    static_pose = static.pose(0)
    dynamic_poses = [dynamic.pose(frame) for frame in range(num_frames)]
    animated = bool(dynamic.primitives)
    gains, offsets = camera_responses(len(world.cameras), seed, COLOR_INCONSISTENCY in effects)
    noisy = SENSOR_NOISE in effects
    train_ids = [c for c in range(len(world.cameras)) if c not in world.test_cameras]
    points_rng = np.random.default_rng([seed, 31])
    per_camera = max(
        1, min(round(POINTS_PER_PIXEL * world.width * world.height), MAX_POINTS // len(train_ids))
    )
    points = []
    total = len(world.cameras) * num_frames
    views = progress_bar(
        total=total, desc="generate", unit="view", disable=not progress, leave=False
    )
    with views:
        for camera_id, camera in enumerate(world.cameras):
            rays = camera_rays(camera, world.width, world.height, SUPERSAMPLE)
            base = Buffers.empty(rays.shape)
            static.render(static_pose, 0.0, rays, base)
            (folder / "ims" / str(camera_id)).mkdir(parents=True)
            (folder / "seg" / str(camera_id)).mkdir(parents=True)
            encoded: tuple[bytes, bytes] | None = None
            for frame in range(num_frames):
                if encoded is None or animated or noisy:
                    buffers = base.copy() if animated else base
                    dynamic.render(dynamic_poses[frame], world.times_s[frame], rays, buffers)
                    if frame == 0 and camera_id in train_ids:
                        points.append(_surface_points(buffers, rays, per_camera, points_rng))
                    noise = noise_generator(seed, camera_id, frame) if noisy else None
                    encoded = _encode_view(buffers, gains[camera_id], offsets[camera_id], noise)
                name = f"{camera_id}/{frame:06d}.png"
                (folder / "ims" / name).write_bytes(encoded[0])
                (folder / "seg" / name).write_bytes(encoded[1])
                views.update(1)
    test_ids = list(world.test_cameras)
    _write_json(folder / TRAIN_META, _meta(world, train_ids))
    _write_json(folder / TEST_META, _meta(world, test_ids))
    np.savez(folder / POINTS_FILE, data=np.concatenate(points).astype(np.float32))


def _encode_view(
    buffers: Buffers, gain: np.ndarray, offset: np.ndarray, noise: np.random.Generator | None
) -> tuple[bytes, bytes]:
    """PNG bytes of (image, mask) after downsampling, the camera response and noise."""
    radiance, coverage = buffers.downsampled(SUPERSAMPLE)
    image = sensor_image(radiance, gain, offset, noise)
    mask = (coverage >= 0.5).astype(np.uint8)
    image_png = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), _PNG_FAST)[1]
    return image_png.tobytes(), cv2.imencode(".png", mask, _PNG_FAST)[1].tobytes()


def _surface_points(
    buffers: Buffers, rays: CameraRays, budget: int, rng: np.random.Generator
) -> np.ndarray:
    """Up to `budget` visible surface samples [n,7] (xyz, radiance rgb, fg) from one camera."""
    hits = np.flatnonzero(np.isfinite(buffers.depth).ravel())
    chosen = np.sort(rng.choice(hits, size=min(budget, len(hits)), replace=False))
    depth = buffers.depth.ravel()[chosen]
    xyz = rays.origin + depth[:, None] * rays.dirs.reshape(-1, 3)[chosen]
    rgb = buffers.color.reshape(-1, 3)[chosen]
    foreground = buffers.foreground.ravel()[chosen].astype(np.float64)
    return np.concatenate([xyz, rgb, foreground[:, None]], axis=1)


def _meta(world: World, camera_ids: list[int]) -> dict:
    """A Panoptic meta dict for `camera_ids`: w, h and per-frame k, w2c, fn, cam_id."""
    ks = [world.cameras[c].K.tolist() for c in camera_ids]
    w2cs = [world.cameras[c].w2c.tolist() for c in camera_ids]
    frames = range(len(world.times_s))
    return {
        "w": world.width,
        "h": world.height,
        "k": [ks for _ in frames],
        "w2c": [w2cs for _ in frames],
        "fn": [[f"{c}/{t:06d}.png" for c in camera_ids] for t in frames],
        "cam_id": [list(camera_ids) for _ in frames],
    }
