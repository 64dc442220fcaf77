"""The Gaussian parameter set: raw tensors, their activations, row operations on them all."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Protocol

import torch
from torch import Tensor, nn

from relaygs.errors import InputError
from relaygs.model.knn import mean_sq_knn_distance
from relaygs.splat.sh import SH_C0, num_sh_bases

MAX_LOG_SCALE = 10.0  # exp(10) ≈ 2.2e4 world units: far beyond any scene, far from float32 inf
MIN_QUAT_SQ_NORM = 1e-16  # |q| below 1e-8 is treated as the zero quaternion → identity
MIN_INIT_SQ_DIST = 1e-7  # 3DGS clamp on the mean squared neighbour distance at init, for a
# cloud of size >= 1; a smaller cloud (a capture in small units) scales it by its size²
CORE_PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")
TENSOR_KEY_SH_DEGREE = "active_sh_degree"
EXTRA_PARAM_PREFIX = "param."
BUFFER_PREFIX = "buffer."


def sh_degree_for_step(step: int, max_degree: int, every: int = 1000) -> int:
    """SH degree active at `step`: one more every `every` steps (3DGS schedule), capped."""
    if every <= 0:
        return max_degree
    return max(0, min(max_degree, step // every))


def sh_of_degree(sh_dc: Tensor, sh_rest: Tensor, degree: int) -> Tensor:
    """SH coefficients [N,(d+1)²,3] for degree d from the DC [N,1,3] and rest [N,R,3] rows."""
    max_degree = math.isqrt(sh_rest.shape[1] + 1) - 1
    if not 0 <= degree <= max_degree:
        raise InputError(f"colors: sh_degree {degree} outside [0, {max_degree}]")
    return torch.cat([sh_dc, sh_rest[:, : num_sh_bases(degree) - 1]], dim=1)


def inverse_sigmoid(p: Tensor, eps: float = 1e-6) -> Tensor:
    """Logit of probabilities clamped to [eps, 1 − eps] so the result is always finite
    (computed in at least float32: in half precision 1 − eps would round to 1)."""
    wide = p.to(torch.promote_types(p.dtype, torch.float32)).clamp(eps, 1.0 - eps)
    return torch.log(wide / (1.0 - wide)).to(p.dtype)


def normalize_quats(quats: Tensor) -> Tensor:
    """Unit quaternions (wxyz); rows with |q| < 1e-8 become identity, with zero, finite grads."""
    sq_norm = (quats * quats).sum(dim=-1, keepdim=True)
    degenerate = sq_norm < MIN_QUAT_SQ_NORM
    identity = torch.zeros_like(quats)
    identity[..., 0] = 1.0
    safe_quats = torch.where(degenerate, identity, quats)
    safe_norm = torch.sqrt(torch.where(degenerate, torch.ones_like(sq_norm), sq_norm))
    return safe_quats / safe_norm


class RowReader(Protocol):
    """What reads a set's rows for a training render in its place (model.row_adam.RowAdam)."""

    def select(self, name: str, rows: Tensor) -> Tensor: ...


class GaussianSet:
    """Raw per-Gaussian parameters and buffers with 3DGS activations: means, log_scales [N,3],
    quats [N,4] (wxyz), opacity_logits [N], sh_dc [N,1,3], sh_rest [N,(d+1)²−1,3]."""

    def __init__(
        self,
        core: Mapping[str, Tensor],
        extra_params: Mapping[str, Tensor] | None = None,
        buffers: Mapping[str, Tensor] | None = None,
        active_sh_degree: int = 0,
    ) -> None:
        """Wrap `core` (all six CORE_PARAMS), optional extras and buffers; tensors are copied."""
        missing = [name for name in CORE_PARAMS if name not in core]
        if missing:
            raise InputError(f"GaussianSet: missing core parameter(s) {missing}")
        self._params: dict[str, nn.Parameter] = {}
        self._buffers: dict[str, Tensor] = {}
        self.row_reader: RowReader | None = None  # set by the optimiser that steps it by rows
        n = core["means"].shape[0]
        for name in CORE_PARAMS:
            self._params[name] = _new_param(core[name], name, n)
        expected = {
            "means": (n, 3),
            "log_scales": (n, 3),
            "quats": (n, 4),
            "opacity_logits": (n,),
            "sh_dc": (n, 1, 3),
        }
        for name, shape in expected.items():
            if tuple(self._params[name].shape) != shape:
                raise InputError(
                    f"GaussianSet: {name} must be {shape}, got {tuple(self._params[name].shape)}"
                )
        rest = tuple(self._params["sh_rest"].shape)
        valid_counts = {num_sh_bases(d) - 1 for d in range(5)}
        if len(rest) != 3 or rest[0] != n or rest[2] != 3 or rest[1] not in valid_counts:
            raise InputError(f"GaussianSet: sh_rest must be [N,(d+1)^2-1,3], got {rest}")
        self.max_sh_degree = math.isqrt(self._params["sh_rest"].shape[1] + 1) - 1
        self.active_sh_degree = active_sh_degree
        for name, values in (extra_params or {}).items():
            self.add_param(name, values)
        for name, values in (buffers or {}).items():
            self.add_buffer(name, values)

    @classmethod
    def from_points(
        cls, xyz: Tensor, rgb: Tensor, max_sh_degree: int = 3, init_opacity: float = 0.1
    ) -> GaussianSet:
        """3DGS initialisation from xyz [N,3] and rgb [N,3] in [0, 1], on the points' device."""
        if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.shape[0] == 0:
            raise InputError(f"from_points: xyz must be [N>0, 3], got {tuple(xyz.shape)}")
        if rgb.shape != xyz.shape:
            raise InputError(f"from_points: rgb must be {tuple(xyz.shape)}, got {tuple(rgb.shape)}")
        xyz = xyz.detach().to(torch.float32)
        n = xyz.shape[0]
        # the floor × the squared bounding-box diagonal when under 1 (a scene in mm must not start
        # with Gaussians larger than itself), at least float32's tiny; on the device, no host read
        size = torch.linalg.vector_norm(xyz.amax(dim=0) - xyz.amin(dim=0))
        unit = torch.where((size > 0.0) & (size < 1.0), size, torch.ones_like(size))
        floor = (MIN_INIT_SQ_DIST * unit * unit).clamp_min(torch.finfo(torch.float32).tiny)
        sq_dist = torch.maximum(mean_sq_knn_distance(xyz, k=3), floor)
        log_scale = 0.5 * torch.log(sq_dist)
        quats = xyz.new_zeros(n, 4)
        quats[:, 0] = 1.0
        core = {
            "means": xyz,
            "log_scales": log_scale[:, None].expand(n, 3),
            "quats": quats,
            "opacity_logits": inverse_sigmoid(xyz.new_full((n,), init_opacity)),
            "sh_dc": ((rgb.detach().to(xyz.device, torch.float32) - 0.5) / SH_C0)[:, None, :],
            "sh_rest": xyz.new_zeros(n, num_sh_bases(max_sh_degree) - 1, 3),
        }
        return cls(core)

    def __len__(self) -> int:
        return self._params["means"].shape[0]

    @property
    def params(self) -> dict[str, nn.Parameter]:
        """All learnable per-Gaussian parameters by name: core first, then extras."""
        return dict(self._params)

    @property
    def buffers(self) -> dict[str, Tensor]:
        return dict(self._buffers)

    @property
    def extra_param_names(self) -> list[str]:
        """Names of the registered extra parameters, in registration order."""
        return [name for name in self._params if name not in CORE_PARAMS]

    def add_param(self, name: str, values: Tensor) -> nn.Parameter:
        """Register a learnable extra per-Gaussian parameter (leading dim N); returns it."""
        self._check_new_name(name)
        self._params[name] = _new_param(values, name, len(self))
        return self._params[name]

    def add_buffer(self, name: str, values: Tensor) -> Tensor:
        """Register a non-learned per-Gaussian tensor (leading dim N); returns the stored copy."""
        self._check_new_name(name)
        _check_rows(values, name, len(self))
        self._buffers[name] = values.detach().clone()
        return self._buffers[name]

    def select_rows(self, name: str, rows: Tensor) -> Tensor:
        """Rows of parameter `name` for a training render: through the set's row reader where an
        optimiser steps it by rows (it brings them up to date and takes their gradient)."""
        if self.row_reader is not None:
            return self.row_reader.select(name, rows)
        return self._params[name].index_select(0, rows)

    @property
    def means(self) -> nn.Parameter:
        """Gaussian centres [N,3] (world units)."""
        return self._params["means"]

    @property
    def scales(self) -> Tensor:
        """exp(log_scales) [N,3], log-scales clamped to MAX_LOG_SCALE first so never inf."""
        return torch.exp(self._params["log_scales"].clamp(max=MAX_LOG_SCALE))

    @property
    def quats(self) -> Tensor:
        """Unit rotation quaternions [N,4] (wxyz); degenerate rows become identity."""
        return normalize_quats(self._params["quats"])

    @property
    def opacities(self) -> Tensor:
        return torch.sigmoid(self._params["opacity_logits"])

    def colors(self, sh_degree: int | None = None) -> Tensor:
        """SH coefficients [N,(d+1)²,3] for degree d (default: the active degree)."""
        degree = self.active_sh_degree if sh_degree is None else sh_degree
        return sh_of_degree(self._params["sh_dc"], self._params["sh_rest"], degree)

    def to_tensors(self, prefix: str = "") -> dict[str, Tensor]:
        """Flat dict of detached copies: core names, `param.<extra>`, `buffer.<name>`, SH degree."""
        out = {prefix + name: self._params[name].detach().clone() for name in CORE_PARAMS}
        for name in self.extra_param_names:
            out[f"{prefix}{EXTRA_PARAM_PREFIX}{name}"] = self._params[name].detach().clone()
        for name, values in self._buffers.items():
            out[f"{prefix}{BUFFER_PREFIX}{name}"] = values.clone()
        out[prefix + TENSOR_KEY_SH_DEGREE] = torch.tensor(self.active_sh_degree, dtype=torch.int64)
        return out

    @classmethod
    def from_tensors(cls, tensors: Mapping[str, Tensor], prefix: str = "") -> GaussianSet:
        """Inverse of `to_tensors` over the keys starting with `prefix` (unknown keys rejected)."""
        core: dict[str, Tensor] = {}
        extras: dict[str, Tensor] = {}
        buffers: dict[str, Tensor] = {}
        sh_degree = 0
        for key, value in tensors.items():
            if not key.startswith(prefix):
                continue
            name = key[len(prefix) :]
            if name in CORE_PARAMS:
                core[name] = value
            elif name.startswith(EXTRA_PARAM_PREFIX):
                extras[name[len(EXTRA_PARAM_PREFIX) :]] = value
            elif name.startswith(BUFFER_PREFIX):
                buffers[name[len(BUFFER_PREFIX) :]] = value
            elif name == TENSOR_KEY_SH_DEGREE:
                sh_degree = int(value.item())
            else:
                raise InputError(f"from_tensors: unknown Gaussian tensor key {key!r}")
        return cls(core, extras, buffers, active_sh_degree=sh_degree)

    def subset(self, rows: Tensor) -> GaussianSet:
        """New set holding the selected rows (bool mask [N] or int64 indices), copied."""
        index = as_row_index(rows, len(self))
        return GaussianSet(
            {name: self._params[name].detach()[index] for name in CORE_PARAMS},
            {name: self._params[name].detach()[index] for name in self.extra_param_names},
            {name: values[index] for name, values in self._buffers.items()},
            active_sh_degree=self.active_sh_degree,
        )

    def concat(self, other: GaussianSet) -> GaussianSet:
        """New set with self's rows then other's; both must register the same extras/buffers."""
        mine, theirs = self.to_tensors(), other.to_tensors()
        if sorted(mine) != sorted(theirs):
            raise InputError(f"concat: tensor names differ: {sorted(mine)} vs {sorted(theirs)}")
        if other.max_sh_degree != self.max_sh_degree:
            raise InputError(
                f"concat: max SH degree differs: {self.max_sh_degree} vs {other.max_sh_degree}"
            )
        joined = {key: torch.cat([mine[key], theirs[key]]) for key in mine if mine[key].ndim}
        joined[TENSOR_KEY_SH_DEGREE] = mine[TENSOR_KEY_SH_DEGREE]
        return GaussianSet.from_tensors(joined)

    def clone(self) -> GaussianSet:
        return self.subset(torch.arange(len(self)))

    def to(self, device: torch.device | str) -> GaussianSet:
        return GaussianSet.from_tensors(
            {key: value.to(device) for key, value in self.to_tensors().items()}
        )

    def reindex_rows_(self, source: Tensor, overrides: Mapping[str, Tensor] | None = None) -> None:
        """In place: row i becomes old row source[i], `overrides` give whole tensors by name; new
        nn.Parameters replace the old (tell the optimiser: `GaussianOptimizer.reindex_rows`)."""
        overrides = overrides or {}
        index = as_row_index(source, len(self))
        m = index.shape[0]
        for name, param in self._params.items():
            values = overrides[name] if name in overrides else param.detach()[index]
            self._params[name] = _new_param(values, name, m)
        for name, values in self._buffers.items():
            new_values = overrides[name] if name in overrides else values[index]
            _check_rows(new_values, name, m)
            self._buffers[name] = new_values.detach()

    def _check_new_name(self, name: str) -> None:
        if name in self._params or name in self._buffers or name == TENSOR_KEY_SH_DEGREE:
            raise InputError(f"GaussianSet: name {name!r} is already registered")
        if not name or "." in name:
            raise InputError(f"GaussianSet: name {name!r} must be non-empty without '.'")


def _new_param(values: Tensor, name: str, rows: int) -> nn.Parameter:
    _check_rows(values, name, rows)
    if not values.is_floating_point():
        raise InputError(
            f"GaussianSet: parameter {name!r} must be floating point, got {values.dtype}"
        )
    return nn.Parameter(values.detach().clone().contiguous(), requires_grad=True)


def _check_rows(values: Tensor, name: str, rows: int) -> None:
    if values.ndim == 0 or values.shape[0] != rows:
        raise InputError(
            f"GaussianSet: {name!r} must have {rows} rows, got shape {tuple(values.shape)}"
        )


def as_row_index(rows: Tensor, n: int) -> Tensor:
    """int64 row indices from a bool mask [n] or an integer index tensor."""
    if rows.dtype == torch.bool:
        if rows.shape != (n,):
            raise InputError(f"GaussianSet: row mask must be [{n}], got {tuple(rows.shape)}")
        return rows.nonzero().squeeze(1)
    return rows.to(torch.int64)
