"""Synthetic scenes: layout, determinism, and that each effect is present only when declared."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import TINY_SYNTH_SIZE
from refusals import refused
from relaygs.data import load_scene
from relaygs.data.effects import (
    BACKGROUND_JITTER,
    COLOR_INCONSISTENCY,
    DYNAMIC_PANELS,
    FAST_OBJECTS,
    LARGE_MOTION,
    NONRIGID,
    SENSOR_NOISE,
    parse_effects,
)
from relaygs.data.synthetic import GENERATOR_VERSION, PRESETS, generate
from relaygs.data.synthetic.actors import HEAD_RADIUS
from relaygs.data.synthetic.render import Buffers, Layer, camera_rays
from relaygs.data.synthetic.rig import look_at
from relaygs.data.synthetic.sensor import NOISE_SIGMA
from relaygs.data.synthetic.world import RigCamera
from relaygs.errors import InputError


def _images(root: Path, folder: str, camera: int) -> list[np.ndarray]:
    paths = sorted((root / folder / str(camera)).glob("*.png"))
    return [cv2.imread(str(path), cv2.IMREAD_UNCHANGED) for path in paths]


def _tree_digest(root: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        if path.is_file():
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def _foreground(preset: str, effects: set[str], frames: int = 64) -> list:
    primitives = PRESETS[preset].build(np.linspace(0.0, 5.0, frames), frozenset(effects), 0)
    return [p for p in primitives if p.foreground]


def _torsos(primitives: list) -> list:
    return [p for p in primitives if p.kind == "capsule" and p.dims == (0.19, 0.16)]


def test_layout_and_declaration(tiny_synth_scene: Path):
    declaration = json.loads((tiny_synth_scene / "scene.json").read_text())
    assert declaration["generator_version"] == GENERATOR_VERSION
    assert declaration["preset"] == "juggle"
    assert (declaration["frames"], declaration["width"], declaration["height"]) == (6, 32, 18)
    assert set(declaration["effects"]) == PRESETS["juggle"].default_effects
    assert declaration["test_cameras"] == [0, 10, 15, 30]
    test_meta = json.loads((tiny_synth_scene / "test_meta.json").read_text())
    train_meta = json.loads((tiny_synth_scene / "train_meta.json").read_text())
    assert test_meta["cam_id"][0] == [0, 10, 15, 30]
    assert len(train_meta["cam_id"][0]) == 27 and len(train_meta["fn"]) == 6
    image = cv2.imread(str(tiny_synth_scene / "ims" / train_meta["fn"][3][2]))
    assert image.shape == (18, 32, 3)
    mask = cv2.imread(str(tiny_synth_scene / "seg" / train_meta["fn"][3][2]), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(mask)) <= {0, 1}


def test_generation_is_deterministic_for_a_seed(tmp_path: Path):
    small = {"frames": 3, "width": 24, "height": 14}
    first = generate("court", tmp_path / "a", seed=5, **small)
    second = generate("court", tmp_path / "b", seed=5, **small)
    third = generate("court", tmp_path / "c", seed=6, **small)
    assert _tree_digest(first) == _tree_digest(second)
    assert _tree_digest(first) != _tree_digest(third)
    meta = json.loads((first / "train_meta.json").read_text())
    assert (meta["w"], meta["h"], len(meta["cam_id"][0]) + 4) == (24, 14, 34)
    assert cv2.imread(str(first / "ims" / meta["fn"][1][0])).shape == (14, 24, 3)


def test_court_without_effects_is_still_and_each_background_effect_adds_motion(tmp_path: Path):
    size = {"frames": 4, "width": 32, "height": 18}
    still = generate("court", tmp_path / "still", effects=[], **size)
    for effect in (DYNAMIC_PANELS, BACKGROUND_JITTER):
        moving = generate("court", tmp_path / effect, effects=[effect], **size)
        changed = 0
        for camera in range(0, 34, 3):
            still_frames = _images(still, "ims", camera)
            assert all(np.array_equal(still_frames[0], frame) for frame in still_frames[1:])
            frames = _images(moving, "ims", camera)
            changed += sum(not np.array_equal(frames[0], frame) for frame in frames[1:])
            masks = _images(moving, "seg", camera)
            assert all(np.array_equal(masks[0], mask) for mask in masks[1:])
        assert changed > 0, effect


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_declaring_an_effect_changes_no_material_of_the_scene(preset: str):
    # an effect may add primitives (fast objects) or move them, but every material of the
    # scene without it is still there: toggling jitter once redrew the spectators' clothes
    recipe = PRESETS[preset]
    times = np.linspace(0.0, 5.0, 4)
    for effect in sorted(recipe.supported_effects):
        without = recipe.build(times, recipe.supported_effects - {effect}, 0)
        with_it = recipe.build(times, recipe.supported_effects, 0)
        # the one material field an effect sets is the panels' animation (dynamic_panels)
        kept = [re.sub(r"animated=\w+", "", repr(p.material)) for p in without]
        added = [re.sub(r"animated=\w+", "", repr(p.material)) for p in with_it]
        missing = [m for m in kept if m not in added]
        assert not missing, (effect, missing[:2])


def test_surface_radiance_is_the_same_from_every_camera():
    primitives = PRESETS["static"].build(np.zeros(1), frozenset(), 0)
    layer = Layer(primitives)
    point = np.array([0.37, -0.52, 0.0])
    colors = []
    for camera in PRESETS["static"].rig(32, 18):
        eye = -camera.w2c[:3, :3].T @ camera.w2c[:3, 3]
        single = RigCamera(
            np.array([[10.0, 0, 0.5], [0, 10.0, 0.5], [0, 0, 1]]), look_at(eye, point)
        )
        rays = camera_rays(single, 1, 1, 1)
        buffers = Buffers.empty((1, 1))
        layer.render(layer.pose(0), 0.0, rays, buffers)
        assert buffers.depth[0, 0] == pytest.approx(np.linalg.norm(point - eye), rel=1e-9)
        colors.append(buffers.color[0, 0])
    colors = np.array(colors)
    assert np.ptp(colors, axis=0).max() < 1e-6
    assert colors[0].max() > 0.05


def _affine_fit(source: np.ndarray, target: np.ndarray) -> tuple[float, float, float]:
    keep = (target > 3) & (target < 252) & (source > 3) & (source < 252)
    x, y = source[keep].astype(np.float64), target[keep].astype(np.float64)
    gain, offset = np.polyfit(x, y, 1)
    return gain, offset, float(np.abs(gain * x + offset - y).max())


def test_static_scenes_are_still_and_simulate_only_the_camera_effects_declared(
    tmp_path: Path, capsys
):
    plain = generate("static", tmp_path / "plain", **TINY_SYNTH_SIZE)
    assert capsys.readouterr().err == ""  # no progress bar unless asked
    for camera in (0, 13, 30):
        frames = _images(plain, "ims", camera)
        assert len(frames) == 6
        assert all(np.array_equal(frames[0], frame) for frame in frames[1:])
        assert not any(mask.any() for mask in _images(plain, "seg", camera))
    size = TINY_SYNTH_SIZE
    tinted = generate(
        "static", tmp_path / "tinted", effects=[COLOR_INCONSISTENCY], progress=True, **size
    )
    views = len(PRESETS["static"].rig(size["width"], size["height"])) * size["frames"]
    shown = capsys.readouterr().err
    assert shown.startswith("\r") and "generate:" in shown and f"0/{views} " in shown
    response = json.loads((tinted / "scene.json").read_text())["camera_response"]
    identity = json.loads((plain / "scene.json").read_text())["camera_response"]
    assert np.allclose(identity["gains"], 1.0) and np.allclose(identity["offsets"], 0.0)
    fitted_gains = []
    for camera in (0, 7, 20):
        source = _images(plain, "ims", camera)[0][..., ::-1]
        target = _images(tinted, "ims", camera)[0][..., ::-1]
        for channel in range(3):
            gain, offset, residual = _affine_fit(source[..., channel], target[..., channel])
            assert residual <= 2.0
            assert gain == pytest.approx(response["gains"][camera][channel], abs=0.03)
            assert offset / 255 == pytest.approx(response["offsets"][camera][channel], abs=0.01)
            fitted_gains.append(gain)
    assert np.ptp(fitted_gains) > 0.05
    noisy = generate("static", tmp_path / "noisy", effects=[SENSOR_NOISE], **size)
    frames = [frame.astype(np.float64) for frame in _images(noisy, "ims", 4)]
    difference = (frames[1] - frames[0]) / 255.0
    assert difference.std() == pytest.approx(np.sqrt(2) * NOISE_SIGMA, rel=0.3)


@pytest.mark.parametrize(("preset", "walk"), [("court", 9.0), ("juggle", 10 * 0.34)])
def test_people_walk_many_body_widths_only_with_large_motion(preset: str, walk: float):
    def path_lengths(effects: set[str]) -> list[float]:
        torsos = _torsos(_foreground(preset, effects))
        return [float(np.linalg.norm(np.diff(t.positions, axis=0), axis=1).sum()) for t in torsos]

    assert min(path_lengths({LARGE_MOTION})) > walk  # court: most of its 15 m
    assert max(path_lengths({NONRIGID})) < 1e-9


def test_burst_people_stand_for_the_first_half_and_run_a_circle_in_the_second():
    for torso in _torsos(_foreground("burst", {LARGE_MOTION, NONRIGID})):
        steps = np.linalg.norm(np.diff(torso.positions, axis=0), axis=1)  # 64 frames over 5 s
        assert steps[:31].max() < 1e-9  # frames 0-31 lie before the half-way 2.5 s
        assert steps[32:].min() > 0.1  # a 1.4 m circle in 2.5 s: about 0.27 m a frame
        assert np.linalg.norm(torso.positions[-1] - torso.positions[31]) < 0.3  # back round
    assert all(
        np.ptp(torso.positions, axis=0).max() < 1e-9
        for torso in _torsos(_foreground("burst", set()))
    )


def _limb_offsets(primitives: list) -> np.ndarray:
    torso = _torsos(primitives)[0]
    limbs = [p for p in primitives if p.kind == "capsule" and p is not torso][:8]
    offsets = [
        np.einsum("fji,fj->fi", torso.rotations, limb.positions - torso.positions) for limb in limbs
    ]
    return np.stack(offsets)


@pytest.mark.parametrize(("preset", "swing"), [("court", 0.2), ("juggle", 0.05)])
def test_limbs_swing_only_when_nonrigid_is_declared(preset: str, swing: float):
    rigid = _limb_offsets(_foreground(preset, {LARGE_MOTION}))
    assert np.ptp(rigid, axis=1).max() < 1e-9
    moving = _limb_offsets(_foreground(preset, {LARGE_MOTION, NONRIGID}))
    assert np.ptp(moving, axis=1).max() > swing


@pytest.mark.parametrize(
    ("declared", "effects"),
    [
        (SENSOR_NOISE, {SENSOR_NOISE}),  # one name, not its letters
        ([SENSOR_NOISE, NONRIGID], {SENSOR_NOISE, NONRIGID}),
        ("none", set()),
        (["none"], set()),
        ([], set()),
    ],
)
def test_parse_effects_reads_a_name_a_list_or_none(declared, effects: set[str]):
    assert parse_effects(declared, source="x") == frozenset(effects)


def test_fast_objects_exist_only_when_declared_and_move_fast():
    for preset in ("juggle", "court"):
        without = _foreground(preset, {LARGE_MOTION, NONRIGID})
        with_balls = _foreground(preset, {LARGE_MOTION, NONRIGID, FAST_OBJECTS})
        balls = [p for p in with_balls if p.kind == "sphere" and p.dims != (HEAD_RADIUS,)]
        assert not [p for p in without if p.kind == "sphere" and p.dims != (HEAD_RADIUS,)]
        assert balls
        for ball in balls:
            per_frame = np.linalg.norm(np.diff(ball.positions, axis=0), axis=1)
            assert np.median(per_frame) > 2 * ball.dims[0], preset


def test_foreground_points_land_in_foreground_masks(tiny_synth_scene: Path):
    scene = load_scene(tiny_synth_scene)
    fg_points = scene.points.xyz[scene.points.is_fg]
    assert 20 < len(fg_points) < len(scene.points) // 2
    for view in scene.views_at(0)[::5]:
        mask = scene.mask(view).numpy()
        mask = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        pixels, inside = view.camera.project(fg_points, min_depth=0.0)
        hits = mask[pixels[inside, 1].long().numpy(), pixels[inside, 0].long().numpy()]
        assert hits.mean() > 0.9


def test_people_fill_a_sensible_part_of_the_juggle_images(tiny_synth_scene: Path):
    masks = [mask for camera in range(31) for mask in _images(tiny_synth_scene, "seg", camera)]
    coverage = np.mean([mask.mean() for mask in masks])
    assert 0.01 < coverage < 0.3
    heights = []
    for mask in masks:
        rows = np.flatnonzero(mask.any(axis=1))
        heights.append((rows.max() - rows.min() + 1) / mask.shape[0] if len(rows) else 0.0)
    assert 0.25 < np.median(heights) < 0.9


@pytest.mark.parametrize(
    ("preset", "kwargs", "named"),
    [
        # an image no loader takes (under 4 pixels a side) is refused before it is rendered
        ("juggle", {"width": 3}, ["width", "4", "3"]),
        ("juggle", {"seed": -1}, ["seed", "0"]),
    ],
)
def test_bad_generator_input_is_rejected(tmp_path: Path, preset: str, kwargs: dict, named: list):
    with refused(InputError, *named):
        generate(preset, tmp_path / "out", **kwargs)
    assert not (tmp_path / "out").exists()


def none_builder(times, effects, seed):
    """A preset builder that forgets to return its primitives."""


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        # before: IndexError (list index out of range) while writing the metadata
        ({"test_cameras": (0, 31)}, ["test_cameras", "presets.py", "[0, 31]"]),
        ({"test_cameras": (0, 0)}, ["test_cameras", "[0, 0]"]),
        ({"test_cameras": (-1,)}, ["test_cameras", "[-1]"]),
        ({"test_cameras": tuple(range(31))}, ["test_cameras"]),
        # before: written without a word, scene.json declaring an effect the world lacks
        ({"default_effects": frozenset({DYNAMIC_PANELS})}, ["default_effects", DYNAMIC_PANELS]),
        # before: each written without a word, then refused or mislabelled by `run`
        ({"test_cameras": ()}, ["test_cameras", "[]"]),
        ({"name": "static"}, [".name", "'static'", "'mine'"]),
        ({"supported_effects": frozenset({"large_motoin"})}, ["supported_effects", "large_motoin"]),
        ({"default_effects": set()}, ["default_effects", "frozenset"]),
        # before: a TypeError traceback
        ({"build": none_builder}, [".build", "NoneType"]),
    ],
)
def test_a_new_preset_that_does_not_fit_its_rig_or_effects_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, changes: dict, named: list
):
    preset = dataclasses.replace(PRESETS["static"], **{"name": "mine", **changes})
    monkeypatch.setitem(PRESETS, "mine", preset)
    with refused(InputError, "PRESETS['mine']", *named):
        generate("mine", tmp_path / "out", frames=1, width=8, height=6)
    assert not (tmp_path / "out").exists()


def _scene_holding(*names: str) -> Callable[[Path], tuple[Path, list[Path]]]:
    def make(tmp_path: Path) -> tuple[Path, list[Path]]:
        scene = generate("static", tmp_path / "scene", frames=1, width=8, height=6)
        return scene, [scene / name for name in names]

    return make


@pytest.mark.parametrize(
    ("make", "named"),
    [
        (lambda tmp: (tmp / "notes", [tmp / "notes" / "keep.txt"]), ["notes"]),
        (lambda tmp: (tmp / "scene", [tmp / "scene"]), ["scene", "not a folder"]),
        (lambda tmp: (tmp / "taken" / "scene", [tmp / "taken"]), ["taken", "not a folder"]),
        (_scene_holding("my_results/notes.txt"), ["'my_results'"]),
        (
            _scene_holding("ims/mine/notes.txt", "seg/README", "seg/0/000000.jpg"),
            ["['ims/mine/notes.txt', 'seg/0/000000.jpg', 'seg/README']"],
        ),
    ],
)
def test_refuses_to_overwrite_what_is_not_a_generated_scene(
    tmp_path: Path, make: Callable, named: list
):
    target, kept = make(tmp_path)
    for path in kept:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"mine: {path.name}")
    with refused(InputError, *named):
        generate("static", target, frames=2, width=8, height=6)
    assert all(path.read_text() == f"mine: {path.name}" for path in kept)


def test_a_generated_scene_holding_only_its_own_files_is_replaced(tmp_path: Path):
    scene = generate("static", tmp_path / "scene", frames=1, width=8, height=6)
    generate("static", scene, frames=2, width=8, height=6)
    frames = sorted(path.name for path in (scene / "ims" / "0").iterdir())
    assert frames == ["000000.png", "000001.png"]
