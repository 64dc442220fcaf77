"""Analytic ray casting in a primitive's local frame (sphere, capsule, box, rectangle): per-ray
dims, origins and unit directions → (t [N], inf on a miss; unit normals [N,3])."""

from __future__ import annotations

import numpy as np

NEAR = 1e-4
_TINY = 1e-12

KINDS = ("sphere", "capsule", "box", "rect")
"""Primitive kinds; `dims` holds (radius,), (half_length, radius), (hx, hy, hz) or (hx, hy)."""
Hits = tuple[np.ndarray, np.ndarray]  # (t [N], unit normals [N,3]) of rays against primitives


def local_half_extents(kind: str, dims: tuple[float, ...]) -> np.ndarray:
    """Half sizes [3] of the local axis-aligned box that bounds a primitive."""
    if kind == "sphere":
        return np.full(3, dims[0])
    if kind == "capsule":
        half_length, radius = dims
        return np.array([radius, radius, half_length + radius])
    if kind == "box":
        return np.asarray(dims, dtype=np.float64)
    if kind == "rect":
        return np.array([dims[0], dims[1], 0.0])
    raise ValueError(f"unknown primitive kind {kind!r}")


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _hit_points(origins: np.ndarray, dirs: np.ndarray, t: np.ndarray) -> np.ndarray:
    return origins + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs


def _sphere_t(offsets: np.ndarray, radius: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Entry distance into spheres; `offsets` = ray origin − sphere centre [N,3]."""
    b = _dot(offsets, dirs)
    disc = b * b - (_dot(offsets, offsets) - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (t > NEAR), t, np.inf)


def intersect_sphere(dims: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> Hits:
    """Spheres of radius dims[:, 0] centred at the local origin (hits from outside)."""
    radius = dims[:, 0]
    t = _sphere_t(origins, radius, dirs)
    return t, _hit_points(origins, dirs, t) / radius[:, None]


def intersect_capsule(dims: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> Hits:
    """Capsules around the local z segment ±dims[:, 0] with radius dims[:, 1]."""
    half_length, radius = dims[:, 0], dims[:, 1]
    dx, dy = dirs[:, 0], dirs[:, 1]
    ox, oy = origins[:, 0], origins[:, 1]
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    disc = b * b - a * (ox * ox + oy * oy - radius * radius)
    t_side = (-b - np.sqrt(np.maximum(disc, 0.0))) / np.where(a > _TINY, a, 1.0)
    z_hit = origins[:, 2] + t_side * dirs[:, 2]
    side_ok = (a > _TINY) & (disc >= 0) & (t_side > NEAR) & (np.abs(z_hit) <= half_length)
    t = np.where(side_ok, t_side, np.inf)
    offsets = origins.copy()
    offsets[:, 2] -= half_length
    t = np.minimum(t, _sphere_t(offsets, radius, dirs))
    offsets[:, 2] += 2 * half_length
    t = np.minimum(t, _sphere_t(offsets, radius, dirs))
    points = _hit_points(origins, dirs, t)
    points[:, 2] -= np.clip(points[:, 2], -half_length, half_length)
    return t, points / radius[:, None]


def intersect_box(dims: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> Hits:
    """Axis-aligned boxes with half sizes dims [N,3] centred at the local origin (slabs)."""
    safe = np.where(np.abs(dirs) > _TINY, dirs, np.where(dirs < 0, -_TINY, _TINY))
    t_low = (-dims - origins) / safe
    t_high = (dims - origins) / safe
    t_enter_axes = np.minimum(t_low, t_high)
    t_enter = t_enter_axes.max(axis=1)
    t_exit = np.maximum(t_low, t_high).min(axis=1)
    t = np.where((t_enter <= t_exit) & (t_enter > NEAR), t_enter, np.inf)
    axis = t_enter_axes.argmax(axis=1)
    normals = np.zeros_like(dirs)
    rows = np.arange(len(dirs))
    normals[rows, axis] = -np.sign(safe[rows, axis])
    return t, normals


def intersect_rect(dims: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> Hits:
    """One-sided rectangles in the local z = 0 plane facing +z, |x| ≤ dims[:,0], |y| ≤ dims[:,1]."""
    facing = (dirs[:, 2] < -_TINY) & (origins[:, 2] > 0)
    t = -origins[:, 2] / np.where(facing, dirs[:, 2], -1.0)
    x = origins[:, 0] + t * dirs[:, 0]
    y = origins[:, 1] + t * dirs[:, 1]
    inside = (np.abs(x) <= dims[:, 0]) & (np.abs(y) <= dims[:, 1])
    t = np.where(facing & inside & (t > NEAR), t, np.inf)
    normals = np.zeros_like(dirs)
    normals[:, 2] = 1.0
    return t, normals


INTERSECTORS = (intersect_sphere, intersect_capsule, intersect_box, intersect_rect)
"""Intersection routine per kind, in the order of KINDS."""
