"""Moving things of the presets: articulated people, juggled and passed balls, spectators;
motion is vectorised over frames, each bone one capsule posed per frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relaygs.data.synthetic.textures import HairCap, Material, Solid, Stripes
from relaygs.data.synthetic.world import Primitive

Color = tuple[float, float, float]
Limb = tuple[np.ndarray, np.ndarray]  # (upper, lower) sagittal angles [F] of one arm or leg
LimbPair = tuple[Limb, Limb]  # the (left, right) limbs of a kind

HIP_HEIGHT = 0.93
HEAD_RADIUS = 0.11
HAND_FORWARD = 0.34
HAND_HEIGHT = 1.1
_THIGH, _SHIN = 0.44, 0.44
_UPPER_ARM, _FOREARM = 0.29, 0.27
_SHOULDER_HEIGHT, _SHOULDER_SIDE, _HIP_SIDE = 1.42, 0.21, 0.1


@dataclass(frozen=True)
class Outfit:
    """Colours of one person: striped shirt, trousers, skin, hair."""

    shirt: Color
    shirt_stripe: Color
    trousers: Color
    skin: Color
    hair: Color


@dataclass(frozen=True)
class BodyMotion:
    """Per-frame root xy [F,2], heading [F] and (left, right) limbs of (upper, lower) sagittal
    angles [F]: 0 straight down, positive forward."""

    root: np.ndarray
    heading: np.ndarray
    legs: LimbPair
    arms: LimbPair


def body_rotations(heading: np.ndarray) -> np.ndarray:
    """Rotations [F,3,3] about z by `heading` (body x forward, y left, z up)."""
    cos, sin = np.cos(heading), np.sin(heading)
    rotations = np.zeros((len(heading), 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1] = cos, -sin
    rotations[:, 1, 0], rotations[:, 1, 1] = sin, cos
    rotations[:, 2, 2] = 1.0
    return rotations


def body_to_world(motion: BodyMotion, local: np.ndarray) -> np.ndarray:
    """Body-frame points [F,3] (or one [3]) to world [F,3] along the motion."""
    rotated = np.einsum(
        "fij,fj->fi",
        body_rotations(motion.heading),
        np.broadcast_to(local, (len(motion.heading), 3)),
    )
    rotated[:, :2] += motion.root
    return rotated


def gait_angles(
    phase: np.ndarray, stride: float, arm_swing: float, elbow: float
) -> tuple[LimbPair, LimbPair]:
    """(legs, arms) sagittal angles of a walking/running gait at gait `phase` [F]."""

    def leg(offset: float) -> Limb:
        thigh = stride * np.sin(phase + offset)
        flex = 0.15 + 0.6 * stride * (0.5 + 0.5 * np.sin(phase + offset - 0.5))
        return thigh, thigh - flex

    def arm(offset: float) -> Limb:
        upper = arm_swing * np.sin(phase + offset + np.pi)
        return upper, upper + elbow

    return (leg(0.0), leg(np.pi)), (arm(0.0), arm(np.pi))


def juggling_arms(time_s: np.ndarray, period_s: float) -> LimbPair:
    """Arms held forward with hands circling in the juggling rhythm (left, right)."""

    def arm(side_phase: float) -> Limb:
        angle = 2 * np.pi * time_s / period_s + side_phase
        return 0.25 + 0.12 * np.sin(angle), 1.45 + 0.25 * np.sin(angle + 0.5)

    return arm(0.0), arm(np.pi)


def _bone(
    start: np.ndarray,
    rotations: np.ndarray,
    angle: np.ndarray,
    size: tuple[float, float],
    material: Material,
) -> tuple[Primitive, np.ndarray]:
    """A capsule of (length, radius) `size` from `start` [F,3] at sagittal `angle` [F] of the
    body `rotations` [F,3,3]; returns it and its end."""
    length, radius = size
    local = np.stack([np.sin(angle), np.zeros_like(angle), -np.cos(angle)], axis=1)
    direction = np.einsum("fij,fj->fi", rotations, local)
    lateral = rotations[:, :, 1]
    end = start + length * direction
    x_axis = np.cross(lateral, direction)
    x_axis /= np.linalg.norm(x_axis, axis=1, keepdims=True)
    frame = np.stack([x_axis, lateral, direction], axis=2)
    capsule = Primitive(
        "capsule", (length / 2, radius), frame, (start + end) / 2, material, foreground=True
    )
    return capsule, end


def person(motion: BodyMotion, outfit: Outfit) -> list[Primitive]:
    """Ten primitives of an articulated person: torso, head, upper/lower arms and legs."""
    rotations = body_rotations(motion.heading)
    shirt = Stripes(outfit.shirt, outfit.shirt_stripe, period=0.16, axis=2)
    trousers = Stripes(outfit.trousers, tuple(0.8 * c for c in outfit.trousers), period=0.12)
    skin = Solid(outfit.skin)
    torso_center = body_to_world(motion, np.array([0.0, 0.0, 1.17]))
    head_center = body_to_world(motion, np.array([0.0, 0.0, 1.62]))
    hair = HairCap(outfit.skin, outfit.hair, level=0.03)
    primitives = [
        Primitive("capsule", (0.19, 0.16), rotations, torso_center, shirt, foreground=True),
        Primitive("sphere", (HEAD_RADIUS,), rotations, head_center, hair, foreground=True),
    ]
    for side, sign in ((0, 1.0), (1, -1.0)):
        hip = body_to_world(motion, np.array([0.0, sign * _HIP_SIDE, HIP_HEIGHT]))
        thigh_angle, shin_angle = motion.legs[side]
        thigh, knee = _bone(hip, rotations, thigh_angle, (_THIGH, 0.07), trousers)
        shin, _ = _bone(knee, rotations, shin_angle, (_SHIN, 0.055), trousers)
        shoulder = body_to_world(motion, np.array([0.0, sign * _SHOULDER_SIDE, _SHOULDER_HEIGHT]))
        upper_angle, fore_angle = motion.arms[side]
        upper, elbow = _bone(shoulder, rotations, upper_angle, (_UPPER_ARM, 0.05), shirt)
        fore, _ = _bone(elbow, rotations, fore_angle, (_FOREARM, 0.042), skin)
        primitives.extend([thigh, shin, upper, fore])
    return primitives


def juggled_balls(
    motion: BodyMotion, time_s: np.ndarray, period_s: float, colors: list[Color]
) -> list[Primitive]:
    """A cascade: each ball flies 75% of every `period_s` from one hand to the other."""
    balls = []
    for index, color in enumerate(colors):
        cycle = time_s / period_s + index / len(colors)
        within = np.mod(cycle, 1.0)
        side = np.where(np.mod(np.floor(cycle), 2) == 0, 1.0, -1.0)
        flying = within < 0.75
        u = np.where(flying, within / 0.75, (within - 0.75) / 0.25)
        lateral = np.where(flying, side * (0.1 - 0.31 * u), -side * (_SHOULDER_SIDE - 0.11 * u))
        height = np.where(
            flying, HAND_HEIGHT + 3.6 * u * (1 - u), HAND_HEIGHT - 0.1 * np.sin(np.pi * u)
        )
        local = np.stack([np.full_like(u, HAND_FORWARD + 0.05), lateral, height], axis=1)
        spin, position = body_rotations(2 * np.pi * cycle), body_to_world(motion, local)
        material = Stripes(color, (1.0, 1.0, 1.0), 0.07, axis=0)
        balls.append(Primitive("sphere", (0.07,), spin, position, material, foreground=True))
    return balls


def hand_position(motion: BodyMotion) -> np.ndarray:
    """World position [F,3] in front of the chest where a player holds the ball."""
    return body_to_world(motion, np.array([HAND_FORWARD + 0.05, 0.0, 1.2]))


def passed_ball(
    holders: list[np.ndarray], time_s: np.ndarray, pass_s: float, apex: float
) -> Primitive:
    """A ball passed along `holders` (hand positions [F,3] per player), one pass per `pass_s`."""
    count = len(holders)
    step = np.floor(time_s / pass_s).astype(np.int64)
    u = time_s / pass_s - step
    start_times = step * pass_s
    end_times = (step + 1) * pass_s
    start = _hand_at(holders, step % count, start_times, time_s)
    end = _hand_at(holders, (step + 1) % count, end_times, time_s)
    positions = start + (end - start) * u[:, None]
    positions[:, 2] += 4 * apex * u * (1 - u)
    spin = body_rotations(4 * np.pi * time_s / pass_s)
    material = Stripes((0.9, 0.42, 0.1), (0.15, 0.08, 0.05), 0.06, axis=0)
    return Primitive("sphere", (0.12,), spin, positions, material, foreground=True)


def _hand_at(
    holders: list[np.ndarray], who: np.ndarray, at_s: np.ndarray, time_s: np.ndarray
) -> np.ndarray:
    """Hand position of player `who[f]` at time `at_s[f]`, interpolated along the frames."""
    result = np.zeros((len(who), 3))
    for player, hands in enumerate(holders):
        chosen = who == player
        for axis in range(3):
            result[chosen, axis] = np.interp(at_s[chosen], time_s, hands[:, axis])
    return result


def spectator(
    position: tuple[float, float],
    facing: float,
    outfit: Outfit,
    jitter: np.ndarray | None,
) -> list[Primitive]:
    """A seated spectator (body capsule + head); `jitter` [F,3] offsets make it sway slightly."""
    rotation = body_rotations(np.array([facing]))
    base = np.array([position[0], position[1], 0.0])
    offsets = np.zeros((1, 3)) if jitter is None else jitter
    shirt = Stripes(outfit.shirt, outfit.shirt_stripe, period=0.2, axis=2)
    hair = HairCap(outfit.skin, outfit.hair, level=0.04)
    body_center = base + np.array([0.0, 0.0, 0.85]) + offsets
    head_center = base + np.array([0.0, 0.0, 1.5]) + 1.3 * offsets
    body = Primitive("capsule", (0.3, 0.2), rotation, body_center, shirt)
    return [body, Primitive("sphere", (0.12,), rotation, head_center, hair)]
