"""Turn the `scene` config section into a loaded Scene: validate it up front, generate a
synthetic preset once into a cache folder (under a lock, so parallel jobs generate it once),
or load a capture folder."""

from __future__ import annotations

import hashlib
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from filelock import FileLock

from relaygs.data import Scene, detect_format, load_scene
from relaygs.data.effects import parse_effects
from relaygs.data.options import make_options, require_int
from relaygs.data.scene import MIN_IMAGE_SIDE
from relaygs.data.synthetic import (
    GENERATOR_VERSION,
    MAX_SYNTH_COUNT,
    PRESETS,
    declared_effects,
    generate,
    remove_abandoned_staging,
    require_valid_preset,
    rig_cameras,
)
from relaygs.errors import InputError
from relaygs.paths import require_folder
from relaygs.pipeline.keys import canonical_json
from relaygs.progress import print_labelled

SCENE_FIELDS = frozenset(
    {"name", "preset", "path", "frames", "width", "height", "seed", "effects", "loader"}
)
LOADER_OPTIONS = ("downscale", "max_points", "cache_mb", "test_cameras")
LOADER_PREFIX = "scene.loader."
"""How errors name a run's loader options."""
GENERATED_MARKER = "scene.json"
HASH_LENGTH = 12
RECORDED_LOADING = ("downscale", "max_points", "test_cameras", "effects")
"""The `load_scene` options a run's manifests record (`scene_provenance`), so the artifacts
commands load the scene as it did."""


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene request: a synthetic preset with its size, or a capture folder."""

    name: str
    preset: str | None
    path: Path | None
    frames: int
    width: int
    height: int
    seed: int
    effects: tuple[str, ...] | None
    loader: dict[str, Any] = field(default_factory=dict)

    @property
    def is_synthetic(self) -> bool:
        """True when the scene is generated from a preset rather than read from `path`."""
        return self.path is None


def scene_spec(section: Mapping[str, Any]) -> SceneSpec:
    """Validate the `scene` section (paths already absolute) without doing any work: a capture
    folder in a known layout, or a synthetic preset; errors name the `scene.*` field."""
    _require_known(section, SCENE_FIELDS, "scene")
    label = section.get("name")
    if isinstance(label, bool | list | Mapping):  # str() would label the scene with its text
        raise InputError(f"scene.name: expected a string, got {label!r}")
    effects = section.get("effects")
    if effects is not None:
        effects = tuple(sorted(parse_effects(effects, source="scene.effects")))
    loader = section.get("loader") or {}
    if not isinstance(loader, Mapping):
        raise InputError(f"scene.loader: expected a mapping of loader options, got {loader!r}")
    loader = dict(loader)
    _require_known(loader, LOADER_OPTIONS, "scene.loader")
    options = make_options(**loader, prefix=LOADER_PREFIX)
    counts = {
        name: require_int(
            name, section.get(name), minimum=minimum, prefix="scene.", maximum=MAX_SYNTH_COUNT
        )
        for name, minimum in (("frames", 1), ("width", MIN_IMAGE_SIDE), ("height", MIN_IMAGE_SIDE))
    }
    seed = require_int("seed", section.get("seed"), minimum=0, prefix="scene.")
    path = section.get("path")
    if path is not None:
        root = require_folder(Path(str(path)), "scene.path")
        detect_format(root)
        name = str(section.get("name") or root.name)
        return SceneSpec(name, None, root, **counts, seed=seed, effects=effects, loader=loader)
    preset = section.get("preset")
    if not isinstance(preset, str) or preset not in PRESETS:  # a list is no name (nor hashable)
        raise InputError(
            f"scene.preset: unknown synthetic preset {preset!r} (available: "
            f"{', '.join(sorted(PRESETS))}); or set scene.path=DIR for a capture"
        )
    require_valid_preset(preset, PRESETS[preset])
    declared_effects(PRESETS[preset], effects, source="scene.effects")
    rig = rig_cameras(PRESETS[preset], counts["width"], counts["height"])
    _check_held_out(preset, options.test_cameras, len(rig))
    name = str(section.get("name") or preset)
    return SceneSpec(name, preset, None, **counts, seed=seed, effects=effects, loader=loader)


def _require_known(section: Mapping[str, Any], known: Collection[str], where: str) -> None:
    """Refuse keys of `section` (named `where`) outside `known`, in one line."""
    unknown = sorted(set(section) - set(known))
    if unknown:
        raise InputError(f"{where}: unknown setting(s) {unknown}; expected {sorted(known)}")


def synthetic_folder(spec: SceneSpec, scenes_dir: Path) -> Path:
    """`<scenes_dir>/<preset>-<hash of its parameters>`, the preset's definition among them."""
    params = {
        "preset": spec.preset,
        "definition": PRESETS[spec.preset].definition(),
        "frames": spec.frames,
        "width": spec.width,
        "height": spec.height,
        "seed": spec.seed,
        "effects": None if spec.effects is None else list(spec.effects),
        "generator_version": GENERATOR_VERSION,
    }
    digest = hashlib.sha256(canonical_json(params, "scene").encode()).hexdigest()
    return scenes_dir / f"{spec.preset}-{digest[:HASH_LENGTH]}"


def prepare_scene(spec: SceneSpec, scenes_dir: Path, progress: bool = True) -> Scene:
    """Load the scene, generating a synthetic one first if its cache folder is missing."""
    if not spec.is_synthetic:
        return load_scene(spec.path, **loader_arguments(spec), option_prefix=LOADER_PREFIX)
    folder = synthetic_folder(spec, scenes_dir)
    lock = scenes_dir / ".locks" / f"{folder.name}.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(lock)):
        remove_abandoned_staging(folder, any_writer=True)  # a job killed while generating it
        if not (folder / GENERATED_MARKER).is_file():
            print_labelled(f"generating synthetic scene {spec.preset!r} into {folder}")
            generate(
                spec.preset,
                folder,
                frames=spec.frames,
                width=spec.width,
                height=spec.height,
                seed=spec.seed,
                effects=spec.effects,
                progress=progress,
            )
    return load_scene(folder, **loader_arguments(spec), option_prefix=LOADER_PREFIX)


def loader_arguments(spec: SceneSpec) -> dict[str, Any]:
    """The `load_scene` options a run loads its scene with: `scene.loader`'s, and a capture's
    `scene.effects` (a generated scene has its effects built into its files)."""
    arguments = dict(spec.loader)
    if not spec.is_synthetic and spec.effects is not None:
        arguments["effects"] = spec.effects
    return arguments


def _check_held_out(preset: str, test_cameras: tuple[int, ...] | None, count: int) -> None:
    """Refuse held-out camera ids the rig lacks, or all of them, before generating the scene."""
    if test_cameras is None:
        return
    missing = [camera_id for camera_id in test_cameras if camera_id >= count]
    if missing or len(test_cameras) == count:
        problem = f"cameras {missing} are not in" if missing else "it holds out every camera of"
        raise InputError(
            f"scene.loader.test_cameras: {problem} preset {preset!r} (camera ids 0..{count - 1})"
        )


def scene_provenance(spec: SceneSpec) -> dict[str, Any]:
    """The RECORDED_LOADING options the run set, as JSON values: what its artifacts record of
    how the scene was loaded, beyond its fingerprint."""
    arguments = loader_arguments(spec)
    options = make_options(**arguments)
    recorded = {}
    for name in RECORDED_LOADING:
        if arguments.get(name) is not None:
            value = getattr(options, name)
            recorded[name] = sorted(value) if isinstance(value, tuple | frozenset) else value
    return recorded


def recorded_loading(provenance: Mapping[str, Any]) -> dict[str, Any]:
    """The `load_scene` options a manifest's `provenance` records (`scene_provenance`)."""
    return {name: provenance[name] for name in RECORDED_LOADING if name in provenance}
