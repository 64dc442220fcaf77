"""Splat `Part`s of Gaussian sets (raw parameters, so stages can pass deformed values or an
opacity factor) into cameras, grouped by image size, and map screen gradients back to each set."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from relaygs.data import Camera
from relaygs.model import MAX_LOG_SCALE, GaussianSet, normalize_quats, sh_of_degree
from relaygs.splat import FixedLayer, rasterization
from relaygs.splat.projection import Projection


@dataclass
class Part:
    """Rows of one Gaussian set, raw parameters [n, ·]; `rows` index the set (None = all)."""

    name: str
    rows: Tensor | None
    means: Tensor
    log_scales: Tensor
    quats: Tensor
    opacity_logits: Tensor
    sh: Tensor
    opacity_factor: Tensor | None = None
    frozen: bool = False

    @property
    def count(self) -> int:
        return self.means.shape[0]


def part_of(
    name: str,
    gaussians: GaussianSet,
    sh_degree: int,
    rows: Tensor | None = None,
    frozen: bool = False,
) -> Part:
    """The (selected rows of the) set as a Part; frozen parts are detached (no gradient), as
    are empty sets (nothing to learn, and autograd warns about their zero-size gradients)."""
    frozen = frozen or len(gaussians) == 0
    params = gaussians.params
    names = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")
    if rows is None:
        values = [params[name].detach() if frozen else params[name] for name in names]
    elif frozen:
        values = [params[name].detach().index_select(0, rows) for name in names]
    else:
        # rows before the SH concatenation: the copy and its backward cover the shown rows only
        values = [gaussians.select_rows(name, rows) for name in names]
    *per_row, sh_dc, sh_rest = values
    return Part(name, rows, *per_row, sh_of_degree(sh_dc, sh_rest, sh_degree), frozen=frozen)


def slot_mask(shared: int, slots: list[tuple[int, int]]) -> Tensor:
    """[C, shared + rows] bool for one render of several slots: every camera sees the first
    `shared` rows; slot i's `cameras` cameras (in order) also see its `rows` rows, the next
    block after the previous slot's, and no other slot's."""
    cameras = sum(count for count, _ in slots)
    rows = sum(count for _, count in slots)
    mask = torch.zeros(cameras, shared + rows, dtype=torch.bool)
    mask[:, :shared] = True
    camera, row = 0, shared
    for camera_count, row_count in slots:
        mask[camera : camera + camera_count, row : row + row_count] = True
        camera, row = camera + camera_count, row + row_count
    return mask


_PROJECTION_FIELDS = tuple(f.name for f in dataclasses.fields(Projection))


@dataclass
class Render:
    """Rendered images and alphas (aligned with the cameras) and, per size group, the meta."""

    images: list[Tensor]
    alphas: list[Tensor]
    groups: list[tuple[list[int], dict[str, Any]]]
    parts: list[Part]


class FrozenRenders:
    """Per camera and SH degree, the frozen parts rendered once, reused by splat.FixedLayer."""

    def __init__(self, eps2d: float, antialiased: bool = False) -> None:
        self.eps2d = eps2d
        self.antialiased = antialiased
        self._cache: dict[tuple[int, int], tuple[Camera, dict[str, Tensor]]] = {}

    def layer(self, parts: list[Part], cameras: list[Camera], sh_degree: int) -> FixedLayer:
        """The frozen rows of `parts` as a FixedLayer over all their rows, for `cameras`."""
        missing = [camera for camera in cameras if not self._cached(camera, sh_degree)]
        for camera in missing:
            # One camera per render: a batched render differs from a lone one in the last bits,
            # so the cache must not depend on which cameras happened to be missing together
            # (a stage resumed from a checkpoint starts with an empty cache).
            with torch.no_grad():
                render = splat(
                    [p for p in parts if p.frozen],
                    [camera],
                    sh_degree,
                    eps2d=self.eps2d,
                    antialiased=self.antialiased,
                )
            meta = render.groups[0][1]
            entry = {name: meta[name][0] for name in (*_PROJECTION_FIELDS, "features")}
            entry["colors"], entry["alphas"] = render.images[0], render.alphas[0]
            self._cache[camera.camera_id, sh_degree] = (camera, entry)
        entries = [self._cache[camera.camera_id, sh_degree][1] for camera in cameras]
        stacked = {name: torch.stack([e[name] for e in entries]) for name in entries[0]}
        projection = Projection(**{name: stacked[name] for name in _PROJECTION_FIELDS})
        mask = torch.cat(
            [
                torch.full((p.count,), p.frozen, dtype=torch.bool, device=p.means.device)
                for p in parts
            ]
        )
        return FixedLayer(
            mask, stacked["colors"], stacked["alphas"], projection, stacked["features"]
        )

    def _cached(self, camera: Camera, sh_degree: int) -> bool:
        known = self._cache.get((camera.camera_id, sh_degree), (None,))[0]
        return known is not None and (
            (known.width, known.height) == (camera.width, camera.height)
            and torch.equal(known.K, camera.K)
            and torch.equal(known.w2c, camera.w2c)
        )


def splat(
    parts: list[Part],
    cameras: list[Camera],
    sh_degree: int,
    frozen: FrozenRenders | None = None,
    camera_mask: Tensor | None = None,
    *,
    eps2d: float,
    antialiased: bool = False,
) -> Render:
    """Render the concatenated parts into every camera on black (unclamped), `eps2d` px² added
    to each 2D covariance (the model's, SceneModel.eps2d), `antialiased` keeping each splat's
    screen integral (rasterization's "antialiased" mode, SceneModel.antialiased); with
    `frozen` and a mix of frozen and trainable parts, its renders give the tiles only frozen
    Gaussians touch; `camera_mask` [C, rows of all parts] bool leaves row n out of camera c
    where False."""
    means = torch.cat([p.means for p in parts])
    scales = torch.exp(torch.cat([p.log_scales for p in parts]).clamp(max=MAX_LOG_SCALE))
    quats = normalize_quats(torch.cat([p.quats for p in parts]))
    opacities = torch.sigmoid(torch.cat([p.opacity_logits for p in parts]))
    if any(p.opacity_factor is not None for p in parts):
        factors = [
            torch.ones_like(p.opacity_logits) if p.opacity_factor is None else p.opacity_factor
            for p in parts
        ]
        opacities = opacities * torch.cat(factors)
    colors = torch.cat([p.sh for p in parts])
    mixed = any(p.frozen for p in parts) and not all(p.frozen for p in parts)
    images: list[Tensor] = [means.new_empty(0)] * len(cameras)
    alphas: list[Tensor] = [means.new_empty(0)] * len(cameras)
    groups = []
    for indices in _size_groups(cameras):
        group = [cameras[i] for i in indices]
        device = means.device
        viewmats = torch.stack([c.w2c for c in group]).to(device, torch.float32)
        intrinsics = torch.stack([c.K for c in group]).to(device, torch.float32)
        fixed = frozen.layer(parts, group, sh_degree) if frozen is not None and mixed else None
        group_mask = None if camera_mask is None else camera_mask[indices]
        rendered, rendered_alphas, meta = rasterization(
            means,
            quats,
            scales,
            opacities,
            colors,
            viewmats,
            intrinsics,
            group[0].width,
            group[0].height,
            sh_degree=sh_degree,
            near_plane=group[0].near,
            eps2d=eps2d,
            rasterize_mode="antialiased" if antialiased else "classic",
            fixed=fixed,
            camera_mask=group_mask,
        )
        for slot, index in enumerate(indices):
            images[index] = rendered[slot]
            alphas[index] = rendered_alphas[slot]
        groups.append((indices, meta))
    return Render(images, alphas, groups, parts)


def screen_statistics(render: Render, name: str) -> tuple[Tensor, Tensor, Tensor | None] | None:
    """(means2d grad, radii), each [C, n, 2], of the n rows of set `name` it showed, and those
    rows (None: the whole set); None if the set was not rendered."""
    offset = 0
    located = None
    for part in render.parts:
        if part.name == name:
            located = (offset, part)
        offset += part.count
    if located is None:
        return None
    start, part = located
    grads, radii = [], []
    for _, meta in render.groups:
        means2d = meta["means2d"]
        grad = means2d.grad if means2d.grad is not None else torch.zeros_like(means2d)
        grads.append(grad[:, start : start + part.count])
        radii.append(meta["radii"][:, start : start + part.count])
    return torch.cat(grads), torch.cat(radii), part.rows


def _size_groups(cameras: list[Camera]) -> list[list[int]]:
    """Camera indices grouped by image size and near plane, in first-seen order."""
    groups: dict[tuple[int, int, float], list[int]] = {}
    for index, camera in enumerate(cameras):
        groups.setdefault((camera.width, camera.height, camera.near), []).append(index)
    return list(groups.values())
