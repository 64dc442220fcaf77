"""3DGS density control of one set (docs/method.md); screen gradients go to NDC × C cameras
as in gsplat, only split children get zero Adam moments. `step()` after the optimiser's."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import Tensor

from relaygs.errors import InputError
from relaygs.model.gaussians import GaussianSet, inverse_sigmoid
from relaygs.model.optim import GaussianOptimizer
from relaygs.splat.projection import quat_to_rotmat


@dataclass(frozen=True)
class DensifySettings:
    """Density control of one set (3DGS background defaults); max_screen_radius (px) is off, as
    3DGS's check in effect is (its max_radii2D is zeroed just before)."""

    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    densify_from: int = 500
    densify_until: int = 15_000
    densify_every: int = 100
    opacity_reset_every: int = 3000
    reset_opacity: float = 0.01
    prune_opacity: float = 0.005
    split_count: int = 2
    split_scale_divisor: float = 1.6  # 0.8 × split_count in 3DGS
    max_world_size: float = 0.1  # × scene extent; pruned after the first reset (see above)
    max_screen_radius: float | None = None
    max_gaussians: int | None = None


BACKGROUND_DENSIFY = DensifySettings()
FOREGROUND_DENSIFY = DensifySettings(grad_threshold=1e-4, percent_dense=0.001)
SCHEDULE_KEYS = ("densify_from", "densify_every", "densify_until", "opacity_reset_every")


def paper_schedule() -> dict[str, int]:
    """The presets' (3DGS) schedule: every stage's `densify*` default, scaled by budgets."""
    return {key: getattr(BACKGROUND_DENSIFY, key) for key in SCHEDULE_KEYS}


@dataclass(frozen=True)
class DensifyReport:
    """What one density-control call did."""

    cloned: int = 0
    split: int = 0
    pruned: int = 0
    opacity_reset: bool = False
    total: int = 0


class DensityController:
    """Accumulates screen-space gradient statistics and edits one set (and its Adam state)."""

    def __init__(
        self,
        gaussians: GaussianSet,
        settings: DensifySettings,
        scene_extent: float,
        optimizer: GaussianOptimizer | None = None,
        generator: torch.Generator | None = None,
    ) -> None:
        """Control `gaussians`; if `optimizer` manages it, its Adam rows are kept aligned."""
        if scene_extent <= 0.0:
            raise InputError(f"DensityController: scene_extent must be > 0, got {scene_extent}")
        self.gaussians = gaussians
        self.settings = settings
        self.scene_extent = scene_extent
        self.optimizer = optimizer
        self.generator = generator
        self._reset_stats()

    def accumulate(
        self,
        means2d_grad: Tensor,
        radii: Tensor,
        width: int,
        height: int,
        *,
        cameras: int | None = None,
        rows: Tensor | None = None,
    ) -> None:
        """Add one step's statistics: means2d_grad [C,n,2] (pixels), radii [C,n,2] or [C,n] of
        the set's `rows` (None: all; repeats allowed); `cameras` is the step's camera count
        (default C), whose mean loss scaled each gradient down by it."""
        per_axis = radii if radii.ndim == 3 else radii[..., None]
        visible = (per_axis > 0).all(dim=-1)
        n_cameras = means2d_grad.shape[0] if cameras is None else cameras
        to_ndc = means2d_grad.new_tensor([width / 2.0, height / 2.0]) * n_cameras
        grad_norm = (means2d_grad.detach() * to_ndc).norm(dim=-1)
        grad_sum = torch.where(visible, grad_norm, 0.0).sum(dim=0)
        views = visible.sum(dim=0)
        max_radius = torch.where(visible, per_axis.max(dim=-1).values, 0).amax(dim=0)
        if rows is None:
            self._grad_sum += grad_sum
            self._views += views
            self._max_radii = torch.maximum(self._max_radii, max_radius.to(torch.float32))
            return
        # a row may repeat (a copy drawn twice in one step): sums add, the radius keeps its max
        self._grad_sum.index_add_(0, rows, grad_sum)
        self._views.index_add_(0, rows, views)
        self._max_radii.scatter_reduce_(0, rows, max_radius.to(torch.float32), "amax")

    def mean_grads(self) -> Tensor:
        """Mean NDC-space gradient norm [N] over the views where each Gaussian was visible."""
        return self._grad_sum / self._views.clamp_min(1).to(self._grad_sum.dtype)

    def step(self, step: int) -> DensifyReport | None:
        """Run whatever the schedule asks for at `step`; None when nothing was due."""
        s = self.settings
        if step >= s.densify_until or step <= 0:
            return None
        densify_due = step > s.densify_from and step % s.densify_every == 0
        reset_due = s.opacity_reset_every > 0 and step % s.opacity_reset_every == 0
        if not (densify_due or reset_due):
            return None
        if self.optimizer is not None:
            self.optimizer.settle(self.gaussians)  # every row up to date before it is read
        cloned = split = pruned = 0
        if densify_due:
            cloned, split = self.densify()
            # world-size pruning waits for the first opacity reset (none to wait for when off)
            pruned = self.prune(size_limits=step > s.opacity_reset_every)
            self._reset_stats()
        if reset_due:
            self.reset_opacity()
        return DensifyReport(cloned, split, pruned, reset_due, len(self.gaussians))

    def densify(self) -> tuple[int, int]:
        """Clone small and split large high-gradient Gaussians; returns (cloned, split)."""
        s = self.settings
        g = self.gaussians
        grads = self.mean_grads()
        max_scale = g.scales.detach().amax(dim=1)
        size_limit = s.percent_dense * self.scene_extent
        candidates = grads >= s.grad_threshold
        clone_mask = candidates & (max_scale <= size_limit)
        split_mask = candidates & (max_scale > size_limit)
        clone_mask, split_mask = self._apply_cap(grads, clone_mask, split_mask)
        n_clone, n_split = int(clone_mask.sum()), int(split_mask.sum())
        if n_clone + n_split == 0:
            return 0, 0
        keep_idx = (~split_mask).nonzero().squeeze(1)
        clone_idx = clone_mask.nonzero().squeeze(1)
        parent_idx = split_mask.nonzero().squeeze(1).repeat(s.split_count)
        source = torch.cat([keep_idx, clone_idx, parent_idx])
        fresh = torch.zeros(source.shape[0], dtype=torch.bool, device=source.device)
        fresh[keep_idx.shape[0] + clone_idx.shape[0] :] = True
        child_means, child_log_scales = self._split_children(parent_idx)
        inherited = source[: keep_idx.shape[0] + clone_idx.shape[0]]
        params = g.params
        overrides = {
            "means": torch.cat([params["means"].detach()[inherited], child_means]),
            "log_scales": torch.cat([params["log_scales"].detach()[inherited], child_log_scales]),
        }
        self._reindex(source, fresh, overrides)
        return n_clone, n_split

    def prune(self, size_limits: bool = True) -> int:
        """Remove low-opacity (and, with size_limits, too-large) Gaussians; returns the count."""
        s = self.settings
        g = self.gaussians
        remove = g.opacities.detach() < s.prune_opacity
        if size_limits:
            remove |= g.scales.detach().amax(dim=1) > s.max_world_size * self.scene_extent
            if s.max_screen_radius is not None:
                remove |= self._max_radii > s.max_screen_radius
        n_removed = int(remove.sum())
        if n_removed:
            keep = (~remove).nonzero().squeeze(1)
            self._reindex(keep, None, None)
        return n_removed

    def reset_opacity(self) -> None:
        """Opacity ← min(opacity, reset value) through the logit; zero its Adam moments."""
        param = self.gaussians.params["opacity_logits"]
        ceiling = inverse_sigmoid(torch.tensor(self.settings.reset_opacity))
        with torch.no_grad():
            param.copy_(torch.minimum(param, ceiling.to(param)))
        if self.optimizer is not None:
            self.optimizer.reset_state(param)

    def state_dict(self) -> dict[str, Tensor]:
        """The accumulated statistics (for in-stage checkpoints), copied."""
        return {
            "grad_sum": self._grad_sum.clone(),
            "views": self._views.clone(),
            "max_radii": self._max_radii.clone(),
        }

    def load_state_dict(self, state: Mapping[str, Tensor]) -> None:
        """Restore statistics saved by `state_dict`; their rows must match the set's."""
        n = len(self.gaussians)
        for key in ("grad_sum", "views", "max_radii"):
            if key not in state or state[key].shape != (n,):
                raise InputError(f"DensityController state: {key!r} must be a tensor of [{n}]")
        device = self.gaussians.means.device
        self._grad_sum = state["grad_sum"].to(device, torch.float32).clone()
        self._views = state["views"].to(device, torch.int64).clone()
        self._max_radii = state["max_radii"].to(device, torch.float32).clone()

    def _split_children(self, parent_idx: Tensor) -> tuple[Tensor, Tensor]:
        g = self.gaussians
        with torch.no_grad():
            stds = g.scales[parent_idx]
            noise = torch.randn(stds.shape, generator=self.generator, device=stds.device)
            rotations = quat_to_rotmat(g.quats[parent_idx])
            offsets = (rotations @ (noise * stds)[..., None]).squeeze(-1)
            means = g.means.detach()[parent_idx] + offsets
            shrink = math.log(self.settings.split_scale_divisor)
            log_scales = g.params["log_scales"].detach()[parent_idx] - shrink
        return means, log_scales

    def _apply_cap(
        self, grads: Tensor, clone_mask: Tensor, split_mask: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Keep only the highest-gradient candidates whose growth fits under max_gaussians."""
        cap = self.settings.max_gaussians
        if cap is None:
            return clone_mask, split_mask
        growth = clone_mask.long() + split_mask.long() * (self.settings.split_count - 1)
        budget = cap - len(self.gaussians)
        if int(growth.sum()) <= budget:
            return clone_mask, split_mask
        candidates = (clone_mask | split_mask).nonzero().squeeze(1)
        order = candidates[grads[candidates].argsort(descending=True, stable=True)]
        fits = growth[order].cumsum(0) <= budget
        chosen = torch.zeros_like(clone_mask)
        chosen[order[fits]] = True
        return clone_mask & chosen, split_mask & chosen

    def _reindex(self, source: Tensor, fresh: Tensor | None, overrides: dict | None) -> None:
        """Remap rows of the set, its Adam state and the statistics (fresh rows start at 0)."""
        if self.optimizer is not None:
            self.optimizer.reindex_rows(self.gaussians, source, fresh, overrides)
        else:
            self.gaussians.reindex_rows_(source, overrides)
        for name in ("_grad_sum", "_views", "_max_radii"):
            rows = getattr(self, name)[source]
            if fresh is not None:
                rows[fresh] = 0
            setattr(self, name, rows)

    def _reset_stats(self) -> None:
        n = len(self.gaussians)
        device = self.gaussians.means.device
        self._grad_sum = torch.zeros(n, device=device)
        self._views = torch.zeros(n, dtype=torch.int64, device=device)
        self._max_radii = torch.zeros(n, device=device)
