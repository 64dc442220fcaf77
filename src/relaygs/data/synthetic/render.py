"""Supersampled ray casting into colour, depth and foreground buffers: each Layer casts its
primitives' rays (within their screen boxes) together by kind, the nearest hit winning."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relaygs.data.synthetic.geometry import INTERSECTORS, KINDS
from relaygs.data.synthetic.textures import shade
from relaygs.data.synthetic.world import Primitive, RigCamera

_NEAR_Z = 0.05
_CHUNK = 1 << 17


@dataclass(frozen=True)
class CameraRays:
    """World-space unit rays through every supersample centre of one camera."""

    origin: np.ndarray
    dirs: np.ndarray
    K: np.ndarray
    w2c: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.dirs.shape[0], self.dirs.shape[1]


@dataclass
class Buffers:
    """Supersample buffers: radiance [h,w,3], ray distance [h,w] (inf = void), foreground."""

    color: np.ndarray
    depth: np.ndarray
    foreground: np.ndarray

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> Buffers:
        """Black void everywhere."""
        color = np.zeros((*shape, 3), dtype=np.float32)
        return cls(color, np.full(shape, np.inf), np.zeros(shape, dtype=bool))

    def copy(self) -> Buffers:
        return Buffers(self.color.copy(), self.depth.copy(), self.foreground.copy())

    def downsampled(self, factor: int) -> tuple[np.ndarray, np.ndarray]:
        """(mean radiance [H,W,3], foreground coverage [H,W]) over factor×factor blocks."""
        color = np.zeros_like(self.color[::factor, ::factor])
        coverage = np.zeros(color.shape[:2], dtype=np.float32)
        for row in range(factor):
            for col in range(factor):
                color += self.color[row::factor, col::factor]
                coverage += self.foreground[row::factor, col::factor]
        return color / factor**2, coverage / factor**2


def camera_rays(camera: RigCamera, width: int, height: int, supersample: int) -> CameraRays:
    """Rays through the centres (j + 0.5) / supersample of the supersample grid."""
    K = np.diag([supersample, supersample, 1.0]) @ camera.K
    cols = np.arange(width * supersample) + 0.5
    rows = np.arange(height * supersample) + 0.5
    u, v = np.meshgrid(cols, rows)
    pixels = np.stack([u, v, np.ones_like(u)], axis=-1)
    rotation = camera.w2c[:3, :3]
    dirs = pixels @ np.linalg.inv(K).T @ rotation
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    origin = -rotation.T @ camera.w2c[:3, 3]
    return CameraRays(origin, dirs, K, camera.w2c)


@dataclass(frozen=True)
class LayerPose:
    """A layer's rotations [P,3,3], positions [P,3] and box corners [P,8,3] at one frame."""

    rotations: np.ndarray
    positions: np.ndarray
    corners: np.ndarray


class Layer:
    """A set of primitives cast together; frame-independent attributes are gathered once."""

    def __init__(self, primitives: list[Primitive]) -> None:
        """Gather the primitives' kinds, sizes, flags and materials into arrays."""
        self.primitives = primitives
        self.kinds = np.array([KINDS.index(p.kind) for p in primitives], dtype=np.int64)
        self.dims = np.zeros((len(primitives), 3))
        for index, primitive in enumerate(primitives):
            self.dims[index, : len(primitive.dims)] = primitive.dims
        self.foreground = np.array([p.foreground for p in primitives], dtype=bool)
        self.materials = list({id(p.material): p.material for p in primitives}.values())
        material_index = {id(material): i for i, material in enumerate(self.materials)}
        self.material_of = np.array(
            [material_index[id(p.material)] for p in primitives], dtype=np.int64
        )

    def pose(self, frame: int) -> LayerPose:
        """Every primitive's pose and bounding-box corners at `frame`."""
        if not self.primitives:
            return LayerPose(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros((0, 8, 3)))
        poses = [primitive.pose(frame) for primitive in self.primitives]
        return LayerPose(
            np.stack([rotation for rotation, _ in poses]),
            np.stack([position for _, position in poses]),
            np.stack([primitive.world_corners(frame) for primitive in self.primitives]),
        )

    def render(self, pose: LayerPose, time_s: float, rays: CameraRays, buffers: Buffers) -> None:
        """Cast the layer at `pose` into `buffers`, keeping the nearest surface per sample."""
        x0, y0, widths, counts = _screen_boxes(pose.corners, rays)
        ends = np.cumsum(counts)
        origins = np.einsum("pji,pj->pi", pose.rotations, rays.origin - pose.positions)
        for start in range(0, int(ends[-1]) if len(ends) else 0, _CHUNK):
            sample = np.arange(start, min(start + _CHUNK, int(ends[-1])))
            owner = np.searchsorted(ends, sample, side="right")
            within = sample - (ends[owner] - counts[owner])
            rows = y0[owner] + within // widths[owner]
            cols = x0[owner] + within % widths[owner]
            self._cast(pose, origins, owner, rows, cols, time_s, rays, buffers)

    def _cast(
        self,
        pose: LayerPose,
        origins_per_primitive: np.ndarray,
        owner: np.ndarray,
        rows: np.ndarray,
        cols: np.ndarray,
        time_s: float,
        rays: CameraRays,
        buffers: Buffers,
    ) -> None:
        rotations = pose.rotations[owner]
        dirs = np.einsum("nji,nj->ni", rotations, rays.dirs[rows, cols])
        origins = origins_per_primitive[owner]
        t = np.full(len(owner), np.inf)
        normals = np.zeros((len(owner), 3))
        kinds = self.kinds[owner]
        for code, intersector in enumerate(INTERSECTORS):
            chosen = np.flatnonzero(kinds == code)
            if len(chosen):
                t[chosen], normals[chosen] = intersector(
                    self.dims[owner[chosen]], origins[chosen], dirs[chosen]
                )
        hits = np.flatnonzero(t < buffers.depth[rows, cols])
        if len(hits) == 0:
            return
        flat = rows[hits] * buffers.depth.shape[1] + cols[hits]
        order = np.lexsort((t[hits], flat))
        hits, flat = hits[order], flat[order]
        hits = hits[np.concatenate([[True], flat[1:] != flat[:-1]])]
        local = origins[hits] + t[hits, None] * dirs[hits]
        albedo = np.zeros((len(hits), 3))
        material = self.material_of[owner[hits]]
        for index in np.unique(material):
            chosen = material == index
            albedo[chosen] = self.materials[index].albedo(local[chosen], time_s)
        world_normals = np.einsum("nij,nj->ni", rotations[hits], normals[hits])
        target = (rows[hits], cols[hits])
        buffers.color[target] = shade(albedo, world_normals)
        buffers.depth[target] = t[hits]
        buffers.foreground[target] = self.foreground[owner[hits]]


def _screen_boxes(
    corners: np.ndarray, rays: CameraRays
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per primitive (corners [P,8,3]) its screen box (x0, y0, width, sample count): none behind
    the camera or beyond one side of the frustum, the whole image across the near plane."""
    rows, cols = rays.shape
    cam = corners @ rays.w2c[:3, :3].T + rays.w2c[:3, 3]
    depth = cam[..., 2]
    safe = np.where(depth > _NEAR_Z, depth, 1.0)
    u = rays.K[0, 0] * cam[..., 0] / safe + rays.K[0, 2]
    v = rays.K[1, 1] * cam[..., 1] / safe + rays.K[1, 2]
    x0 = np.clip(np.floor(u.min(axis=1)), 0, cols).astype(np.int64)
    x1 = np.clip(np.ceil(u.max(axis=1)) + 1, 0, cols).astype(np.int64)
    y0 = np.clip(np.floor(v.min(axis=1)), 0, rows).astype(np.int64)
    y1 = np.clip(np.ceil(v.max(axis=1)) + 1, 0, rows).astype(np.int64)
    in_front = depth > _NEAR_Z
    outside_a_side = (
        (rays.K[0, 0] * cam[..., 0] + rays.K[0, 2] * depth < 0).all(axis=1)
        | (rays.K[0, 0] * cam[..., 0] + (rays.K[0, 2] - cols) * depth > 0).all(axis=1)
        | (rays.K[1, 1] * cam[..., 1] + rays.K[1, 2] * depth < 0).all(axis=1)
        | (rays.K[1, 1] * cam[..., 1] + (rays.K[1, 2] - rows) * depth > 0).all(axis=1)
    )
    in_front &= ~outside_a_side[:, None]
    straddles = in_front.any(axis=1) & ~in_front.all(axis=1)
    x0, y0 = np.where(straddles, 0, x0), np.where(straddles, 0, y0)
    x1, y1 = np.where(straddles, cols, x1), np.where(straddles, rows, y1)
    widths = np.maximum(x1 - x0, 0)
    counts = np.where(in_front.any(axis=1), widths * np.maximum(y1 - y0, 0), 0)
    return x0, y0, widths, counts
