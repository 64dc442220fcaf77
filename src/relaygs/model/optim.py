"""One Adam over "<set>.<param>" groups with lr schedules (positions × the scene extent, as
3DGS); a set whose steps each show a few of its rows (the relay copies) is stepped by rows."""

from __future__ import annotations

import functools
import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field, fields

import torch
from torch import Tensor, nn

from relaygs.errors import InputError
from relaygs.model.gaussians import GaussianSet, as_row_index
from relaygs.model.row_adam import BETA1, BETA2, RowAdam

ADAM_EPS = 1e-15


def log_linear(
    lr_init: float,
    lr_final: float,
    step: int,
    max_steps: int,
    delay_steps: int = 0,
    delay_mult: float = 1.0,
) -> float:
    """3DGS `get_expon_lr_func`: log-linear lr_init → lr_final over max_steps (≤ 0: done), times
    delay_mult rising to 1 (sine ease) over delay_steps."""
    if lr_init == 0.0 and lr_final == 0.0:
        return 0.0
    if lr_init <= 0.0 or lr_final <= 0.0:
        raise InputError(
            f"log_linear: lr_init and lr_final must both be > 0 (or both 0), "
            f"got {lr_init} and {lr_final}"
        )
    if step < 0:
        return 0.0
    if delay_steps > 0:
        ramp = min(max(step / delay_steps, 0.0), 1.0)
        delay_rate = delay_mult + (1.0 - delay_mult) * math.sin(0.5 * math.pi * ramp)
    else:
        delay_rate = 1.0
    t = min(max(step / max_steps, 0.0), 1.0) if max_steps > 0 else 1.0
    return delay_rate * math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


@dataclass(frozen=True)
class LRSchedule:
    """A learning rate: constant `init`, or log-linear init → final over max_steps."""

    init: float
    final: float | None = None
    max_steps: int = 0
    delay_steps: int = 0
    delay_mult: float = 1.0

    def at(self, step: int) -> float:
        """Learning rate at `step`."""
        if self.final is None:
            return self.init
        return log_linear(
            self.init, self.final, step, self.max_steps, self.delay_steps, self.delay_mult
        )

    @classmethod
    def from_config(cls, value: float | Mapping[str, float]) -> LRSchedule:
        """From a number (constant) or a mapping of fields (`relaygs.stages.config` checks both)."""
        return cls(float(value)) if isinstance(value, int | float) else cls(**dict(value))


@dataclass(frozen=True)
class SetLearningRates:
    """Learning-rate schedules for the parameters of one Gaussian set (3DGS defaults)."""

    means: LRSchedule = LRSchedule(1.6e-4, 1.6e-6, 30_000, 0, 0.01)
    log_scales: LRSchedule = LRSchedule(5e-3)
    quats: LRSchedule = LRSchedule(1e-3)
    opacity_logits: LRSchedule = LRSchedule(0.05)
    sh_dc: LRSchedule = LRSchedule(2.5e-3)
    sh_rest: LRSchedule = LRSchedule(2.5e-3 / 20)
    extras: Mapping[str, LRSchedule] = field(default_factory=dict)

    def for_param(self, name: str) -> LRSchedule:
        """The schedule for parameter `name` (core or a registered extra)."""
        if name in self.extras:
            return self.extras[name]
        if name != "extras" and name in {f.name for f in fields(self)}:
            return getattr(self, name)
        raise InputError(f"learning rates: no schedule for parameter {name!r}")

    @classmethod
    def from_config(cls, config: Mapping[str, object], where: str = "lr") -> SetLearningRates:
        """Build from a mapping: core names and `extras` → number or schedule mapping."""
        core_names = {f.name for f in fields(cls)} - {"extras"}
        unknown = sorted(set(config) - core_names - {"extras"})
        if unknown:
            raise InputError(f"{where}: unknown learning-rate keys {unknown}")
        core = {
            name: LRSchedule.from_config(value)
            for name, value in config.items()
            if name != "extras"
        }
        extras_config = config.get("extras") or {}
        extras = {
            name: LRSchedule.from_config(value) for name, value in dict(extras_config).items()
        }
        return cls(**core, extras=extras)


@functools.cache
def has_fused_adam(device: torch.device) -> bool:
    """Whether this torch has a fused Adam kernel for DEVICE, by building and stepping a probe."""
    probe = torch.zeros(1, device=device, requires_grad=True)
    probe.grad = torch.zeros_like(probe)
    try:
        torch.optim.Adam([probe], fused=True).step()
    except RuntimeError:
        return False
    return True


def adam(groups: list[dict]) -> torch.optim.Adam:
    """Adam, eps 1e-15, over param groups: fused where torch can (faster), else foreach."""
    fused = has_fused_adam(groups[0]["params"][0].device)
    kernel = {"fused": True} if fused else {"foreach": True}
    return torch.optim.Adam(groups, lr=0.0, betas=(BETA1, BETA2), eps=ADAM_EPS, **kernel)


class GaussianOptimizer:
    """Adam (eps 1e-15) with one param group per (set, parameter), named "<set>.<param>"; the
    sets in `row_sets` are stepped by the rows each step shows (RowAdam), the rest by torch."""

    def __init__(
        self,
        sets: Mapping[str, GaussianSet],
        learning_rates: Mapping[str, SetLearningRates],
        spatial_lr_scale: float = 1.0,
        row_sets: Collection[str] = (),
    ) -> None:
        """Build groups for every parameter of every set; extras must have a schedule."""
        self.sets = dict(sets)
        self.spatial_lr_scale = spatial_lr_scale
        self._schedules: dict[str, LRSchedule] = {}
        self._rates: dict[str, float] = {}
        groups = []
        for set_name, gaussians in self.sets.items():
            for param_name, param in gaussians.params.items():
                group_name = f"{set_name}.{param_name}"
                schedule = learning_rates[set_name].for_param(param_name)
                self._schedules[group_name] = schedule
                if set_name not in row_sets:
                    groups.append({"params": [param], "name": group_name, "lr": schedule.at(0)})
        self.adam = adam(groups) if groups else None
        fused = has_fused_adam(next(iter(self.sets.values())).means.device) if sets else False
        self.row_adams = {
            name: RowAdam(
                self.sets[name], functools.partial(self._rate, name), ADAM_EPS, fused=fused
            )
            for name in row_sets
            if name in self.sets
        }
        self.update_learning_rates(0)

    def update_learning_rates(self, step: int) -> dict[str, float]:
        """Set every group's lr for `step`; returns {group name: lr}."""
        for name, schedule in self._schedules.items():
            lr = schedule.at(step)
            self._rates[name] = lr * self.spatial_lr_scale if name.endswith(".means") else lr
        for group in self.adam.param_groups if self.adam is not None else []:
            group["lr"] = self._rates[group["name"]]
        return dict(self._rates)

    def step(self) -> None:
        """One Adam step of every set."""
        if self.adam is not None:
            self.adam.step()
        for row_adam in self.row_adams.values():
            row_adam.step()

    def zero_grad(self) -> None:
        """Drop every gradient."""
        if self.adam is not None:
            self.adam.zero_grad(set_to_none=True)
        for row_adam in self.row_adams.values():
            row_adam.zero_grad()

    def row_gradients(self) -> dict[str, Tensor]:
        """This step's gradients of the row-stepped sets, "<set>.<param>" (flattened)."""
        return {
            f"{set_name}.{name}": grad
            for set_name, row_adam in self.row_adams.items()
            for name, grad in row_adam.gradients().items()
        }

    def settle(self, gaussians: GaussianSet | None = None) -> None:
        """Bring the rows of a row-stepped set (None: of every one) up to date."""
        for row_adam in self.row_adams.values():
            if gaussians is None or row_adam.gaussians is gaussians:
                row_adam.settle()

    def reindex_rows(
        self,
        gaussians: GaussianSet,
        source: Tensor,
        fresh_state: Tensor | None = None,
        overrides: Mapping[str, Tensor] | None = None,
    ) -> None:
        """Row i takes old row source[i], values and Adam state (zeroed where `fresh_state`)."""
        self.settle(gaussians)
        old_params = gaussians.params
        index = as_row_index(source, len(gaussians))
        gaussians.reindex_rows_(index, overrides)
        row_adam = self._row_adam_of(gaussians)
        if row_adam is not None:
            row_adam.reindex(index, fresh_state)
            return
        for name, old in old_params.items():
            self._swap_param(old, gaussians.params[name], index, fresh_state)

    def reset_state(self, param: nn.Parameter) -> None:
        """Zero the Adam moments of `param`."""
        found = self._row_param(param)
        if found is not None:
            row_adam, name = found
            row_adam.settle()
            row_adam.reset(name)
            return
        for key, value in self.adam.state.get(param, {}).items() if self.adam else []:
            if key != "step" and torch.is_tensor(value):
                value.zero_()

    def state_of(self, param: nn.Parameter) -> dict[str, Tensor]:
        """The Adam moments of `param` (empty before its first step of a torch-stepped set)."""
        found = self._row_param(param)
        if found is not None:
            row_adam, name = found
            return row_adam.moments(name)
        return dict(self.adam.state.get(param, {})) if self.adam is not None else {}

    def _row_adam_of(self, gaussians: GaussianSet) -> RowAdam | None:
        return next((r for r in self.row_adams.values() if r.gaussians is gaussians), None)

    def _row_param(self, param: nn.Parameter) -> tuple[RowAdam, str] | None:
        """The RowAdam stepping `param` and the parameter's name in its set, if any."""
        for row_adam in self.row_adams.values():
            for name, candidate in row_adam.gaussians.params.items():
                if candidate is param:
                    return row_adam, name
        return None

    def _rate(self, set_name: str, param_name: str) -> float:
        return self._rates[f"{set_name}.{param_name}"]

    def _swap_param(
        self, old: nn.Parameter, new: nn.Parameter, index: Tensor, fresh: Tensor | None
    ) -> None:
        for group in self.adam.param_groups:
            for slot, param in enumerate(group["params"]):
                if param is old:
                    group["params"][slot] = new
                    break
        state = self.adam.state.pop(old, None)
        if not state:
            return
        new_state = {}
        for key, value in state.items():
            if key == "step" or not torch.is_tensor(value) or value.shape != old.shape:
                new_state[key] = value
                continue
            rows = value[index]
            if fresh is not None:
                rows[fresh] = 0.0
            new_state[key] = rows
        self.adam.state[new] = new_state
