"""HexPlane, the 4D-GS space-time grid the deformation MLPs read: six planes per level, sampled
bilinearly and multiplied; time t in [0, 1] spans the grid's [-1, 1]."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from relaygs.errors import InputError
from relaygs.field.hexplane_native import NativeHexPlaneFeatures, NativeSecondDifferenceEnergy
from relaygs.splat import native_kernels_in_use

SPATIAL_PLANES = ("xy", "xz", "yz")
TIME_PLANES = ("xt", "yt", "zt")
SPATIAL_INIT_RANGE = (0.1, 0.5)
MIN_HALF_EXTENT = 1e-6  # a thinner box axis gets a unit half-extent: no division by zero


def second_difference_energy(planes: Tensor, dims: Sequence[int]) -> Tensor:
    """Sum over planes [P, C, H, W] and over `dims` (2, 3 or both) of the mean squared second
    difference along that dim (0 for a dim shorter than 3)."""
    dims = [dim for dim in dims if planes.shape[dim] >= 3]
    if not dims:
        return planes.new_zeros(())
    if native_kernels_in_use(planes):
        return NativeSecondDifferenceEnergy.apply(planes, 2 in dims, 3 in dims)
    return sum(_SecondDifferenceEnergy.apply(planes, dim) for dim in dims)


class _SecondDifferenceEnergy(torch.autograd.Function):
    """second_difference_energy with its gradient in closed form, (2/M)·Dᵀ(D planes): one pass
    each way, half the cost of autograd's narrow/expand chain on the finest planes."""

    @staticmethod
    def forward(ctx: Any, planes: Tensor, dim: int) -> Tensor:
        length = planes.shape[dim]
        curvature = planes.narrow(dim, 0, length - 2) - 2.0 * planes.narrow(dim, 1, length - 2)
        curvature += planes.narrow(dim, 2, length - 2)
        ctx.save_for_backward(curvature)
        ctx.dim, ctx.shape = dim, planes.shape
        return curvature.square().mean(dim=(1, 2, 3)).sum()

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None]:
        (curvature,) = ctx.saved_tensors
        dim, length = ctx.dim, curvature.shape[ctx.dim]
        scaled = curvature * (grad * (2.0 / curvature[0].numel()))
        planes_grad = curvature.new_zeros(ctx.shape)
        planes_grad.narrow(dim, 0, length).add_(scaled)
        planes_grad.narrow(dim, 1, length).add_(scaled, alpha=-2.0)
        planes_grad.narrow(dim, 2, length).add_(scaled)
        return planes_grad, None


def _sample(planes: Tensor, grid: Tensor) -> Tensor:
    """Bilinear, border-padded, corner-aligned samples of P planes at P point sets: [P, C, N]."""
    sampled = F.grid_sample(
        planes, grid, mode="bilinear", padding_mode="border", align_corners=True
    )
    return sampled.squeeze(2)


class HexPlane(nn.Module):
    """Multi-resolution planes giving features [N, channels·levels]; per level [3, C, R, R]
    spatial (xy, xz, yz) and [3, C, T, R] time planes (xt, yt, zt): two `grid_sample` calls."""

    def __init__(
        self,
        aabb: Tensor | Sequence[Sequence[float]],
        time_resolution: int,
        *,
        multires: Sequence[int] = (1, 2),
        spatial_resolution: int = 64,
        channels: int = 16,
    ) -> None:
        """Build planes for the box `aabb` ([2, 3]: min row, max row) and `time_resolution` rows."""
        super().__init__()
        lower, upper = _validated_aabb(aabb)
        _require_positive("time_resolution", time_resolution)
        _require_positive("spatial_resolution", spatial_resolution)
        _require_positive("channels", channels)
        if len(multires) == 0:
            raise InputError("HexPlane multires: expected at least one level, got []")
        for factor in multires:
            _require_positive("multires entry", factor)
        half = (upper - lower) / 2.0
        self.register_buffer("center", (upper + lower) / 2.0)
        self.register_buffer(
            "half_extent", torch.where(half > MIN_HALF_EXTENT, half, torch.ones_like(half))
        )
        self.channels = channels
        self.multires = tuple(int(m) for m in multires)
        self.time_resolution = int(time_resolution)
        low, high = SPATIAL_INIT_RANGE
        self.spatial_planes = nn.ParameterList()
        self.time_planes = nn.ParameterList()
        for factor in self.multires:
            res = spatial_resolution * factor
            spatial = torch.empty(len(SPATIAL_PLANES), channels, res, res).uniform_(low, high)
            self.spatial_planes.append(nn.Parameter(spatial))
            time = torch.ones(len(TIME_PLANES), channels, self.time_resolution, res)
            self.time_planes.append(nn.Parameter(time))

    @property
    def feature_dim(self) -> int:
        """Width of the feature vector returned per point."""
        return self.channels * len(self.multires)

    def normalise(self, xyz: Tensor) -> Tensor:
        """Map world positions into the grid's [-1, 1]^3 by the construction bounding box."""
        return (xyz - self.center) / self.half_extent

    def forward(self, xyz: Tensor, t: float | Tensor) -> Tensor:
        """Features [N, feature_dim] at `xyz` [N, 3], times `t` in [0, 1] (scalar or [N]); points
        or times outside the box or [0, 1] read the border value."""
        if xyz.dim() != 2 or xyz.shape[1] != 3:
            raise InputError(f"HexPlane xyz: expected shape [N, 3], got {list(xyz.shape)}")
        count = xyz.shape[0]
        coords = self.normalise(xyz)
        times = _time_coordinate(t, count, xyz)
        if native_kernels_in_use(coords) and not times.requires_grad:
            levels = zip(self.spatial_planes, self.time_planes, strict=True)
            planes = [plane for level in levels for plane in level]
            return NativeHexPlaneFeatures.apply(coords, times, *planes)
        return self._sampled(coords, times)

    def _sampled(self, coords: Tensor, times: Tensor) -> Tensor:
        """`forward` by torch's grid_sample (any device; the native kernel's reference)."""
        grid_t = times.unsqueeze(1)
        x, y, z = coords[:, 0:1], coords[:, 1:2], coords[:, 2:3]
        # grid[..., 0] indexes a plane's columns (first axis), grid[..., 1] its rows.
        spatial_grid = torch.stack(
            (torch.cat((x, y), 1), torch.cat((x, z), 1), torch.cat((y, z), 1))
        ).unsqueeze(1)
        time_grid = torch.stack(
            (torch.cat((x, grid_t), 1), torch.cat((y, grid_t), 1), torch.cat((z, grid_t), 1))
        ).unsqueeze(1)
        levels = []
        for spatial, time in zip(self.spatial_planes, self.time_planes, strict=True):
            s = _sample(spatial, spatial_grid)
            m = _sample(time, time_grid)
            levels.append((s[0] * s[1] * s[2] * m[0] * m[1] * m[2]).t())
        return torch.cat(levels, dim=1)

    def plane_smoothness(self) -> Tensor:
        """Squared second differences of the spatial planes along both axes, unweighted: twice
        4D-GS's one-axis compute_plane_smoothness at the same weight."""
        terms = [second_difference_energy(p, (2, 3)) for p in self.spatial_planes]
        return torch.stack(terms).sum()

    def time_smoothness(self) -> Tensor:
        """Squared second differences of the xt, yt, zt planes along time, summed like above."""
        return torch.stack([second_difference_energy(p, (2,)) for p in self.time_planes]).sum()

    def time_l1(self) -> Tensor:
        """Mean |1 − value| of each time plane, summed over planes and levels (1 = static)."""
        terms = [(1.0 - p).abs().mean(dim=(1, 2, 3)).sum() for p in self.time_planes]
        return torch.stack(terms).sum()

    def regularisers(self) -> dict[str, Tensor]:
        """The three unweighted grid regularisers, keyed by name."""
        return {
            "plane_smoothness": self.plane_smoothness(),
            "time_smoothness": self.time_smoothness(),
            "time_l1": self.time_l1(),
        }


def _time_coordinate(t: float | Tensor, count: int, like: Tensor) -> Tensor:
    """Times in [0, 1] (scalar or [N]) as grid coordinates over the full [-1, 1], shape [N]."""
    t_tensor = torch.as_tensor(t, dtype=like.dtype, device=like.device)
    if t_tensor.dim() == 0:
        t_tensor = t_tensor.expand(count)
    elif t_tensor.shape != (count,):
        raise InputError(
            f"HexPlane t: expected a scalar or shape [{count}], got {list(t_tensor.shape)}"
        )
    return t_tensor * 2.0 - 1.0


def _validated_aabb(aabb: Tensor | Sequence[Sequence[float]]) -> tuple[Tensor, Tensor]:
    box = torch.as_tensor(aabb, dtype=torch.float32).detach().cpu()
    if box.shape != (2, 3):
        raise InputError(f"HexPlane aabb: expected shape [2, 3] (min, max), got {list(box.shape)}")
    if not bool(torch.isfinite(box).all()) or bool((box[0] > box[1]).any()):
        raise InputError(f"HexPlane aabb: expected finite min <= max per axis, got {box.tolist()}")
    return box[0], box[1]


def _require_positive(name: str, value: int) -> None:
    if int(value) != value or value < 1:
        raise InputError(f"HexPlane {name}: expected a positive integer, got {value!r}")
