"""The synthetic presets (juggle, court, burst, static): their effects and their worlds."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from relaygs.data.effects import (
    BACKGROUND_JITTER,
    COLOR_INCONSISTENCY,
    DYNAMIC_PANELS,
    FAST_OBJECTS,
    LARGE_MOTION,
    NONRIGID,
    SENSOR_NOISE,
)
from relaygs.data.synthetic.actors import (
    BodyMotion,
    Color,
    Outfit,
    gait_angles,
    hand_position,
    juggled_balls,
    juggling_arms,
    passed_ball,
    person,
    spectator,
)
from relaygs.data.synthetic.rig import dome_rig, ring_rig
from relaygs.data.synthetic.studio import arena, dome_studio
from relaygs.data.synthetic.textures import Scoreboard
from relaygs.data.synthetic.world import Primitive, RigCamera, static_pose
from relaygs.errors import InputError

DURATION_S = 5.0
"""Every sequence spans 5 s whatever its frame count (150 frames = 30 fps, as Panoptic)."""
JUGGLE_PERIOD_S = 0.8
PASS_S = 0.625

WorldBuilder = Callable[[np.ndarray, frozenset[str], int], list[Primitive]]


@dataclass(frozen=True)
class Preset:
    """A named scene recipe: rig, default and supported effects, and a primitive builder."""

    name: str
    description: str
    rig: Callable[[int, int], list[RigCamera]]
    test_cameras: tuple[int, ...]
    default_effects: frozenset[str]
    supported_effects: frozenset[str]
    build: WorldBuilder
    revision: int = 1
    """Raised when a change to this preset's builder alters its images (GENERATOR_VERSION is
    for changes to every preset's), so only its cached scenes are generated anew."""

    def definition(self) -> dict[str, Any]:
        """Every field but the description as stable JSON, which the scene cache hashes; the
        revision enters once raised, so an unrevised preset keeps its cache folders."""
        return {
            field.name: _describe(getattr(self, field.name), f"PRESETS[{self.name!r}].{field.name}")
            for field in fields(self)
            if field.name != "description" and (field.name, self.revision) != ("revision", 1)
        }


def _describe(value: object, where: str) -> object:
    """A preset field as JSON (a function by `module.qualname`, a partial by its parts); a lambda
    or nested function has no stable name and is refused naming `where`."""
    if isinstance(value, frozenset):
        return sorted(value)
    if isinstance(value, tuple):
        return [_describe(item, where) for item in value]
    if isinstance(value, functools.partial):
        return {
            "function": _describe(value.func, where),
            "args": [_describe(item, where) for item in value.args],
            "keywords": {key: _describe(item, where) for key, item in value.keywords.items()},
        }
    if callable(value):
        name = getattr(value, "__qualname__", "<unnamed>")
        if "<" in name:
            raise InputError(
                f"{where}: expected a module-level function or a functools.partial of one (its "
                f"name keys the scene cache), got {value!r}"
            )
        return f"{value.__module__}.{name}"
    return value


def _outfit(rng: np.random.Generator, shirt: Color, stripe: Color) -> Outfit:
    skin = tuple(float(v) for v in np.array([0.85, 0.64, 0.5]) * rng.uniform(0.6, 1.05))
    hair = tuple(float(v) for v in rng.uniform(0.05, 0.35, size=3))
    trousers = tuple(float(v) for v in rng.uniform(0.1, 0.45, size=3))
    return Outfit(shirt, stripe, trousers, skin, hair)


def _gait_phase(
    root: np.ndarray, times: np.ndarray, stride: float, effects: frozenset[str], cadence: float
) -> np.ndarray:
    """Gait phase from distance walked; stepping in place when the root does not travel."""
    if NONRIGID not in effects:
        return np.zeros_like(times)
    if LARGE_MOTION not in effects:
        return 2 * np.pi * cadence * times
    steps = np.linalg.norm(np.diff(root, axis=0), axis=1)
    return 2 * np.pi * np.concatenate([[0.0], np.cumsum(steps)]) / stride


def _headings(root: np.ndarray, initial: float) -> np.ndarray:
    """Heading along the direction of travel, holding the last one while (nearly) still."""
    headings = np.full(len(root), initial)
    velocity = np.gradient(root, axis=0) if len(root) > 1 else np.zeros_like(root)
    current = initial
    for index, (vx, vy) in enumerate(velocity):
        if np.hypot(vx, vy) > 1e-6:
            current = float(np.arctan2(vy, vx))
        headings[index] = current
    return headings


def build_juggle(times: np.ndarray, effects: frozenset[str], seed: int) -> list[Primitive]:
    """Two people juggling three balls each while walking round the stage on opposite sides."""
    rng = np.random.default_rng([seed, 11])
    primitives = dome_studio(seed)
    shirts = (((0.8, 0.15, 0.15), (0.95, 0.95, 0.9)), ((0.15, 0.6, 0.25), (0.95, 0.85, 0.2)))
    ball_colors = (
        [(0.95, 0.9, 0.1), (0.1, 0.8, 0.95), (0.95, 0.2, 0.6)],
        [(1.0, 0.5, 0.0), (0.6, 0.2, 0.95), (0.2, 0.95, 0.3)],
    )
    for index in range(2):
        start = index * np.pi + rng.uniform(-0.3, 0.3)
        if LARGE_MOTION in effects:
            angle = start + 2 * np.pi * times / DURATION_S
            heading = angle + np.pi / 2
        else:
            angle = np.full_like(times, start)
            heading = angle + np.pi
        root = 1.4 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
        phase = _gait_phase(root, times, stride=1.3, effects=effects, cadence=0.9)
        legs, _ = gait_angles(phase, stride=0.4, arm_swing=0.0, elbow=0.0)
        pose_times = times if NONRIGID in effects else np.zeros_like(times)
        arms = juggling_arms(pose_times + 0.3 * index, JUGGLE_PERIOD_S)
        motion = BodyMotion(root, heading, legs, arms)
        primitives += person(motion, _outfit(rng, *shirts[index]))
        if FAST_OBJECTS in effects:
            primitives += juggled_balls(
                motion, times + 0.3 * index, JUGGLE_PERIOD_S, ball_colors[index]
            )
    return primitives


def _player_path(
    index: int, times: np.ndarray, effects: frozenset[str], rng: np.random.Generator
) -> np.ndarray:
    direction = 1.0 if index % 2 == 0 else -1.0
    lane = (-3.6, 3.6, -2.2, 2.2, -0.8, 0.8)[index]
    waypoints = [-6.0 * direction, 6.0 * direction]
    if index >= 4:
        waypoints = [-6.0 * direction, 5.0 * direction, -1.0 * direction]
    progress = times / DURATION_S * (len(waypoints) - 1)
    segment = np.minimum(np.floor(progress).astype(np.int64), len(waypoints) - 2)
    eased = 0.5 - 0.5 * np.cos(np.pi * np.clip(progress - segment, 0.0, 1.0))
    points = np.asarray(waypoints)
    x = points[segment] + (points[segment + 1] - points[segment]) * eased
    weave = 0.4 * np.sin(2 * np.pi * times / 2.2 + rng.uniform(0, 2 * np.pi))
    root = np.stack([x, lane + weave], axis=1)
    if LARGE_MOTION not in effects:
        root = np.broadcast_to(root[0], root.shape).copy()
    return root


def build_court(times: np.ndarray, effects: frozenset[str], seed: int) -> list[Primitive]:
    """Six players running the length of the court, a passed ball, panels and spectators."""
    rng = np.random.default_rng([seed, 12])
    primitives = arena(seed)
    teams = (((0.85, 0.12, 0.12), (0.95, 0.95, 0.95)), ((0.1, 0.25, 0.8), (0.95, 0.85, 0.2)))
    hands = []
    for index in range(6):
        root = _player_path(index, times, effects, rng)
        heading = _headings(root, 0.0 if index % 2 == 0 else np.pi)
        phase = _gait_phase(root, times, stride=2.0, effects=effects, cadence=1.4)
        legs, arms = gait_angles(phase, stride=0.6, arm_swing=0.7, elbow=1.3)
        motion = BodyMotion(root, heading, legs, arms)
        primitives += person(motion, _outfit(rng, *teams[index % 2]))
        hands.append(hand_position(motion))
    if FAST_OBJECTS in effects:
        order = [0, 3, 1, 4, 2, 5]
        primitives.append(passed_ball([hands[i] for i in order], times, PASS_S, apex=1.0))
    for sign in (1.0, -1.0):
        board = Scoreboard(1.6, 0.8, seed=seed + int(sign > 0), animated=DYNAMIC_PANELS in effects)
        panel = static_pose((sign * 12.9, 0, 3.8))
        primitives.append(Primitive("box", (0.06, 1.6, 0.8), *panel, board))
    for side in (1.0, -1.0):
        for x in np.linspace(-9.0, 9.0, 7):
            # drawn whether or not the sway is declared: declaring it changes nothing else
            frequency = rng.uniform(0.4, 1.2, size=3)
            phase0 = rng.uniform(0, 2 * np.pi, size=3)
            jitter = None
            if BACKGROUND_JITTER in effects:
                amplitude = np.array([0.08, 0.06, 0.03])
                jitter = amplitude * np.sin(2 * np.pi * frequency * times[:, None] + phase0)
            shirt = tuple(float(v) for v in rng.uniform(0.1, 0.9, size=3))
            outfit = _outfit(rng, shirt, tuple(0.6 * c for c in shirt))
            primitives += spectator((float(x), side * 9.3), -side * np.pi / 2, outfit, jitter)
    return primitives


def build_burst(times: np.ndarray, effects: frozenset[str], seed: int) -> list[Primitive]:
    """Two people standing still for the first half of the sequence, then running a full circle
    round the stage in the second: all the motion in one burst (for motion-adaptive segments)."""
    rng = np.random.default_rng([seed, 13])
    primitives = dome_studio(seed)
    shirts = (((0.2, 0.3, 0.85), (0.95, 0.95, 0.9)), ((0.9, 0.55, 0.1), (0.2, 0.2, 0.25)))
    start_s = DURATION_S / 2
    running_s = np.clip(times - start_s, 0.0, None)
    for index in range(2):
        start = index * np.pi + rng.uniform(-0.3, 0.3)
        angle = np.full_like(times, start)
        if LARGE_MOTION in effects:
            angle = angle + 2 * np.pi * running_s / (DURATION_S - start_s)
        root = 1.4 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
        heading = _headings(root, start + np.pi)  # facing the centre until they set off
        phase = _gait_phase(root, times, stride=2.0, effects=effects, cadence=1.4)
        legs, arms = gait_angles(phase, stride=0.6, arm_swing=0.7, elbow=1.3)
        primitives += person(BodyMotion(root, heading, legs, arms), _outfit(rng, *shirts[index]))
    return primitives


def build_static(times: np.ndarray, effects: frozenset[str], seed: int) -> list[Primitive]:
    """The juggling studio with nobody in it: nothing moves (a control scene)."""
    return dome_studio(seed)


_CAMERA_EFFECTS = frozenset({COLOR_INCONSISTENCY, SENSOR_NOISE})

PRESETS: dict[str, Preset] = {
    "juggle": Preset(
        "juggle",
        "Panoptic-like dome (31 cameras); two people juggling while walking round the stage",
        dome_rig,
        (0, 10, 15, 30),
        frozenset({LARGE_MOTION, NONRIGID, FAST_OBJECTS, COLOR_INCONSISTENCY}),
        frozenset({LARGE_MOTION, NONRIGID, FAST_OBJECTS}) | _CAMERA_EFFECTS,
        build_juggle,
    ),
    "court": Preset(
        "court",
        "Basketball-court ring (34 cameras); six players, a passed ball, panels, spectators",
        ring_rig,
        (0, 10, 20, 30),
        frozenset({LARGE_MOTION, NONRIGID, FAST_OBJECTS, DYNAMIC_PANELS, BACKGROUND_JITTER}),
        frozenset({LARGE_MOTION, NONRIGID, FAST_OBJECTS, DYNAMIC_PANELS, BACKGROUND_JITTER})
        | _CAMERA_EFFECTS,
        build_court,
        revision=2,  # declaring background_jitter no longer redraws the spectators' clothes
    ),
    "burst": Preset(
        "burst",
        "The juggling dome; two people stand still for half the sequence, then run a circle",
        dome_rig,
        (0, 10, 15, 30),
        frozenset({LARGE_MOTION, NONRIGID}),
        frozenset({LARGE_MOTION, NONRIGID}) | _CAMERA_EFFECTS,
        build_burst,
    ),
    "static": Preset(
        "static",
        "The juggling studio and dome with nothing moving (a control scene)",
        dome_rig,
        (0, 10, 15, 30),
        frozenset(),
        _CAMERA_EFFECTS,
        build_static,
    ),
}
"""Preset name → recipe."""
