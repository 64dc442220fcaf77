"""The synthetic world: primitives with per-frame poses and materials, cameras, test split."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relaygs.data.synthetic.geometry import local_half_extents
from relaygs.data.synthetic.textures import Material


@dataclass(frozen=True, eq=False)
class Primitive:
    """A shape in its local frame, posed by rotations [F,3,3] and positions [F,3] (F = 1 when
    still); `foreground` actors make up the foreground masks."""

    kind: str
    dims: tuple[float, ...]
    rotations: np.ndarray
    positions: np.ndarray
    material: Material
    foreground: bool = False

    @property
    def animated(self) -> bool:
        """Whether anything about the primitive (pose or texture) changes over time."""
        moves = len(self.positions) > 1 and not (
            np.allclose(self.positions, self.positions[0])
            and np.allclose(self.rotations, self.rotations[0])
        )
        return moves or self.material.animated

    def pose(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """(rotation [3,3] local→world, position [3]) at `frame`."""
        index = min(frame, len(self.positions) - 1)
        return self.rotations[min(frame, len(self.rotations) - 1)], self.positions[index]

    def world_corners(self, frame: int) -> np.ndarray:
        """The 8 corners [8,3] of the local bounding box, in world coordinates."""
        rotation, position = self.pose(frame)
        half = local_half_extents(self.kind, self.dims)
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        return (signs * half) @ rotation.T + position


@dataclass(frozen=True)
class RigCamera:
    """A generator camera: intrinsics [3,3] and world→camera [4,4] (OpenCV axes), float64."""

    K: np.ndarray
    w2c: np.ndarray


@dataclass(frozen=True)
class World:
    """Everything the renderer needs for one scene: cameras, primitives and timing."""

    cameras: list[RigCamera]
    test_cameras: tuple[int, ...]
    primitives: list[Primitive]
    times_s: np.ndarray
    width: int
    height: int


def static_pose(
    position: tuple[float, float, float], rotation: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(rotations [1,3,3], positions [1,3]) for a primitive that never moves."""
    rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    return rotation[None], np.asarray(position, dtype=np.float64)[None]
