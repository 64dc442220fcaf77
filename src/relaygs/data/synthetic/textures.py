"""Procedural Lambertian materials: albedo from a surface point's local coordinates and time,
so it moves with its primitive and has one colour in every camera."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

_LIGHTS = (
    (np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84]), 0.6),
    (np.array([-0.5, -0.6, 0.62]) / np.linalg.norm([-0.5, -0.6, 0.62]), 0.25),
)
_AMBIENT = 0.3


class Material(Protocol):
    """Albedo of local surface points [N,3] at `time_s`; `animated` if it changes."""

    animated: bool

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Colours [N,3] in [0,1] of the points `local` [N,3] at time `time_s` seconds."""
        ...


def shade(albedo: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Lambertian radiance under two fixed directional lights and an ambient term."""
    light = np.full(len(normals), _AMBIENT)
    for direction, strength in _LIGHTS:
        light += strength * np.maximum(normals @ direction, 0.0)
    return np.clip(albedo * light[:, None], 0.0, 1.0)


def _hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random value in [0, 1) per integer lattice point."""
    ix, iy, iz = (np.asarray(v).astype(np.int64).astype(np.uint32) for v in (ix, iy, iz))
    h = ix * np.uint32(0x8DA6B343)
    h ^= iy * np.uint32(0xD8163841)
    h ^= iz * np.uint32(0xCB1AB31F)
    h ^= np.uint32(seed * 0x9E3779B1 & 0xFFFFFFFF)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x2C1B3C6D)
    h ^= h >> np.uint32(12)
    h *= np.uint32(0x297A2D39)
    h ^= h >> np.uint32(15)
    return h.astype(np.float64) / 2.0**32


def value_noise(points: np.ndarray, seed: int, octaves: int = 2) -> np.ndarray:
    """Smooth 3D value noise in [0, 1] (fractal sum of `octaves` octaves)."""
    total = np.zeros(len(points))
    weight_sum = 0.0
    for octave in range(octaves):
        scaled = points * (2.0**octave)
        cell = np.floor(scaled)
        frac = scaled - cell
        smooth = frac * frac * (3.0 - 2.0 * frac)
        ix, iy, iz = (cell[:, k].astype(np.int64) for k in range(3))
        value = np.zeros(len(points))
        for cx in (0, 1):
            wx = smooth[:, 0] if cx else 1.0 - smooth[:, 0]
            for cy in (0, 1):
                wy = smooth[:, 1] if cy else 1.0 - smooth[:, 1]
                for cz in (0, 1):
                    wz = smooth[:, 2] if cz else 1.0 - smooth[:, 2]
                    value += wx * wy * wz * _hash01(ix + cx, iy + cy, iz + cz, seed + octave)
        weight = 0.5**octave
        total += weight * value
        weight_sum += weight
    return total / weight_sum


def _mix(color_a: np.ndarray, color_b: np.ndarray, select: np.ndarray) -> np.ndarray:
    return np.where(select[:, None], np.asarray(color_b), np.asarray(color_a))


def _grain(
    colors: np.ndarray, local: np.ndarray, seed: int, amount: float, scale: float
) -> np.ndarray:
    if amount == 0.0:
        return colors
    variation = 1.0 + amount * (2.0 * value_noise(local * scale, seed) - 1.0)
    return np.clip(colors * variation[:, None], 0.0, 1.0)


@dataclass(frozen=True)
class Solid:
    """A single colour."""

    color: tuple[float, float, float]
    animated: bool = False

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """The constant colour for every point."""
        return np.broadcast_to(np.asarray(self.color, dtype=np.float64), local.shape).copy()


@dataclass(frozen=True)
class Checker:
    """Checkerboard tiles in local x/y with noisy grain: floors and props."""

    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float]
    size: float
    seed: int
    grain: float = 0.25
    animated: bool = False

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Alternating tiles of `size` metres, each modulated by value noise."""
        cells = np.floor(local[:, :2] / self.size).astype(np.int64)
        colors = _mix(self.color_a, self.color_b, (cells.sum(axis=1) % 2) == 1)
        return _grain(colors, local, self.seed, self.grain, 4.0 / self.size)


@dataclass(frozen=True)
class Stripes:
    """Bands along one local axis: clothing, limbs, poles."""

    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float]
    period: float
    axis: int = 2
    grain: float = 0.0
    seed: int = 0
    animated: bool = False

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Colour b on the second half of every `period` along `axis`."""
        phase = np.mod(local[:, self.axis] / self.period, 1.0)
        colors = _mix(self.color_a, self.color_b, phase >= 0.5)
        return _grain(colors, local, self.seed, self.grain, 6.0)


@dataclass(frozen=True)
class Bricks:
    """Offset brick rows on local x/y (x along the wall, y up) separated by mortar lines."""

    brick: tuple[float, float, float]
    mortar: tuple[float, float, float]
    width: float
    height: float
    seed: int
    animated: bool = False

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Bricks whose tone varies per brick, with thin mortar joints."""
        row = np.floor(local[:, 1] / self.height)
        shifted = local[:, 0] / self.width + 0.5 * np.mod(row, 2)
        column = np.floor(shifted)
        joint_x = (shifted - column) < 0.06
        joint_y = (local[:, 1] / self.height - row) < 0.1
        tone = 0.75 + 0.5 * _hash01(column, row, np.zeros_like(row), self.seed)
        colors = np.clip(np.asarray(self.brick) * tone[:, None], 0.0, 1.0)
        colors = _grain(colors, local, self.seed + 1, 0.15, 8.0)
        return np.where((joint_x | joint_y)[:, None], np.asarray(self.mortar), colors)


@dataclass(frozen=True)
class HairCap:
    """A head: skin colour with hair above local height `level` (metres)."""

    skin: tuple[float, float, float]
    hair: tuple[float, float, float]
    level: float
    animated: bool = False

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Hair on the top and back of the head, skin on the face."""
        hair = (local[:, 2] > self.level) | (local[:, 0] < -0.5 * abs(self.level))
        return _mix(self.skin, self.hair, hair)


@dataclass(frozen=True)
class CourtFloor:
    """A basketball court on local x/y: wooden planks inside, lines, dark surround outside."""

    half_length: float
    half_width: float
    seed: int
    animated: bool = False

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Planks, white lines (border, centre line and circle, keys) and a dark surround."""
        x, y = local[:, 0], local[:, 1]
        plank = np.floor(y / 0.25)
        plank_tone = 0.85 + 0.3 * _hash01(plank, np.floor(x / 2.4 + 0.37 * plank), plank, self.seed)
        wood = np.array([0.78, 0.55, 0.32])[None, :] * plank_tone[:, None]
        wood = _grain(wood, local * np.array([1.0, 8.0, 1.0]), self.seed + 1, 0.2, 1.5)
        inside = (np.abs(x) <= self.half_length) & (np.abs(y) <= self.half_width)
        surround = _grain(np.tile([0.18, 0.2, 0.26], (len(x), 1)), local, self.seed + 2, 0.3, 2.0)
        colors = np.where(inside[:, None], wood, surround)
        return np.where(self._lines(x, y)[:, None], np.array([0.95, 0.95, 0.92]), colors)

    def _lines(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        width = 0.06
        near = np.abs
        border = (near(near(x) - self.half_length) < width) & (near(y) <= self.half_width)
        border |= (near(near(y) - self.half_width) < width) & (near(x) <= self.half_length)
        centre = (near(x) < width) & (near(y) <= self.half_width)
        circle = near(np.hypot(x, y) - 1.8) < width
        key_x = self.half_length - 5.8
        key = (near(near(x) - key_x) < width) & (near(y) <= 2.45)
        key |= (near(near(y) - 2.45) < width) & (near(x) >= key_x) & (near(x) <= self.half_length)
        arc = near(np.hypot(near(x) - self.half_length + 1.6, y) - 6.75) < width
        arc &= near(x) <= self.half_length
        return border | centre | circle | key | arc


@dataclass(frozen=True)
class Scoreboard:
    """An LED panel on local y/z whose lit cells change every `period_s` when animated."""

    half_width: float
    half_height: float
    seed: int
    animated: bool
    period_s: float = 0.3
    columns: int = 12
    rows: int = 5

    def albedo(self, local: np.ndarray, time_s: float) -> np.ndarray:
        """Dark housing with a grid of lit (amber) and dim cells; the pattern steps with time."""
        step = int(np.floor(time_s / self.period_s)) if self.animated else 0
        u = (local[:, 1] / self.half_width + 1.0) * 0.5 * self.columns
        v = (local[:, 2] / self.half_height + 1.0) * 0.5 * self.rows
        column, row = np.floor(u), np.floor(v)
        border = (u - column < 0.15) | (v - row < 0.15)
        lit = _hash01(column, row, np.full_like(row, step), self.seed) > 0.55
        colors = np.where(lit[:, None], np.array([1.0, 0.7, 0.15]), np.array([0.2, 0.12, 0.1]))
        return np.where(border[:, None], np.array([0.05, 0.05, 0.06]), colors)
