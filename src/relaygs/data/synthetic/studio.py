"""Static surroundings: a room of textured floor and walls (open top), props, court fixtures."""

from __future__ import annotations

import numpy as np

from relaygs.data.synthetic.textures import Bricks, Checker, CourtFloor, Material, Stripes
from relaygs.data.synthetic.world import Primitive, static_pose

_UP = np.array([0.0, 0.0, 1.0])


def facing_rotation(normal: np.ndarray) -> np.ndarray:
    """Local→world rotation whose z axis is `normal` (horizontal) and whose y axis points up."""
    normal = np.asarray(normal, dtype=np.float64)
    x_axis = np.cross(_UP, normal)
    return np.stack([x_axis, _UP, normal], axis=1)


def room(
    half_x: float, half_y: float, wall_height: float, floor: Material, walls: list[Material]
) -> list[Primitive]:
    """Floor rectangle plus four inward-facing walls (+x, −x, +y, −y); no ceiling."""
    primitives = [Primitive("rect", (half_x, half_y), *static_pose((0.0, 0.0, 0.0)), floor)]
    sides = (
        ((-1.0, 0.0, 0.0), (half_x, 0.0), half_y),
        ((1.0, 0.0, 0.0), (-half_x, 0.0), half_y),
        ((0.0, -1.0, 0.0), (0.0, half_y), half_x),
        ((0.0, 1.0, 0.0), (0.0, -half_y), half_x),
    )
    for (normal, (x, y), half_length), material in zip(sides, walls, strict=True):
        pose = static_pose((x, y, wall_height / 2), facing_rotation(np.array(normal)))
        primitives.append(Primitive("rect", (half_length, wall_height / 2), *pose, material))
    return primitives


def crate(
    center: tuple[float, float], half: tuple[float, float, float], yaw: float, seed: int
) -> Primitive:
    """A textured box standing on the floor, rotated by `yaw` about z."""
    cos, sin = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    material = Checker((0.62, 0.45, 0.25), (0.4, 0.28, 0.15), size=0.2, seed=seed)
    return Primitive("box", half, *static_pose((*center, half[2]), rotation), material)


def dome_studio(seed: int) -> list[Primitive]:
    """The juggling studio: tiled floor, four different walls and a few crates near the walls."""
    floor = Checker((0.58, 0.55, 0.5), (0.33, 0.32, 0.3), size=0.6, seed=seed)
    walls: list[Material] = [
        Bricks((0.62, 0.3, 0.22), (0.8, 0.78, 0.72), width=0.5, height=0.22, seed=seed + 1),
        Stripes((0.2, 0.35, 0.6), (0.85, 0.85, 0.8), period=0.8, axis=0, grain=0.3, seed=seed + 2),
        Checker((0.3, 0.5, 0.32), (0.7, 0.75, 0.55), size=0.9, seed=seed + 3),
        Bricks((0.75, 0.62, 0.3), (0.3, 0.28, 0.25), width=0.7, height=0.3, seed=seed + 4),
    ]
    props = [
        crate((4.6, 4.4), (0.4, 0.4, 0.4), 0.3, seed + 5),
        crate((-4.8, 4.2), (0.6, 0.3, 0.5), -0.5, seed + 6),
        crate((-4.4, -4.7), (0.35, 0.35, 0.7), 0.9, seed + 7),
        crate((4.3, -4.9), (0.5, 0.5, 0.3), 0.1, seed + 8),
    ]
    return room(6.0, 6.0, 3.5, floor, walls) + props


COURT_HALF_LENGTH = 7.5
COURT_HALF_WIDTH = 4.5


def arena(seed: int) -> list[Primitive]:
    """The court arena: court floor, stands-coloured walls, a hanging backboard at each end."""
    floor = CourtFloor(COURT_HALF_LENGTH, COURT_HALF_WIDTH, seed=seed)
    walls: list[Material] = [
        Stripes((0.15, 0.2, 0.45), (0.3, 0.35, 0.6), period=1.2, axis=1, grain=0.3, seed=seed + 1),
        Stripes((0.45, 0.15, 0.15), (0.6, 0.3, 0.25), period=1.2, axis=1, grain=0.3, seed=seed + 2),
        Bricks((0.5, 0.5, 0.55), (0.25, 0.25, 0.3), width=1.2, height=0.5, seed=seed + 3),
        Checker((0.35, 0.45, 0.4), (0.55, 0.6, 0.5), size=1.5, seed=seed + 4),
    ]
    hoops = []
    for sign in (1.0, -1.0):
        board = Checker((0.92, 0.92, 0.9), (0.85, 0.3, 0.2), size=0.3, seed=seed + 5)
        strut = Stripes((0.3, 0.3, 0.33), (0.5, 0.5, 0.55), period=0.3, axis=2)
        hoops.append(Primitive("box", (0.03, 0.9, 0.53), *static_pose((sign * 7.0, 0, 3.3)), board))
        pole = static_pose((sign * 7.05, 0, 4.9))
        hoops.append(Primitive("box", (0.05, 0.05, 1.1), *pole, strut))
    return room(13.0, 10.0, 6.0, floor, walls) + hoops
