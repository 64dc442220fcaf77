"""What a training stage optimises, as one object, and its state for in-stage checkpoints."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from relaygs.errors import DivergenceError, InputError
from relaygs.model import (
    DensifyReport,
    DensifySettings,
    DensityController,
    GaussianOptimizer,
    GaussianSet,
    LRSchedule,
    SetLearningRates,
    adam,
    check_finite,
    sh_degree_for_step,
)
from relaygs.model.guard import divergence_suspects
from relaygs.pipeline.checkpoint import TrainingState
from relaygs.train.render import Render, screen_statistics

GENERATOR_KEY = "generator"
ROW_ADAM = "row_adam"
DENSITY_GENERATOR_KEY = "density_generator"


@dataclass(frozen=True)
class SetPlan:
    """How one Gaussian set trains: learning rates, density control (None = off), SH schedule,
    and whether it is stepped by the rows each step shows (`GaussianOptimizer` row_sets)."""

    learning_rates: SetLearningRates
    densify: DensifySettings | None
    sh_every: int = 1000
    by_rows: bool = False  # each step shows a few rows (relay copies): Adam steps those rows


@dataclass(frozen=True)
class ModuleGroup:
    """One Adam group of module parameters with its schedule (× scene extent when asked)."""

    name: str
    params: list[nn.Parameter]
    schedule: LRSchedule
    scale_by_extent: bool = False


@dataclass
class TrainingSession:
    """A stage's trainable state; `build` the optimisers again after the sets change."""

    sets: dict[str, GaussianSet]
    plans: dict[str, SetPlan]
    extent: float
    seed: int
    device: torch.device
    modules: dict[str, nn.Module] = field(default_factory=dict)
    module_groups: list[ModuleGroup] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.generator = torch.Generator().manual_seed(self.seed)
        self.density_generator = torch.Generator(self.device).manual_seed(self.seed + 1)
        self._base_sh = {name: g.active_sh_degree for name, g in self.sets.items()}
        self.build()

    def build(self) -> None:
        """(Re)build optimisers and density controllers over the current sets and modules."""
        self.optimizer = GaussianOptimizer(
            self.sets,
            {name: self.plans[name].learning_rates for name in self.sets},
            spatial_lr_scale=self.extent,
            row_sets=[name for name in self.sets if self.plans[name].by_rows],
        )
        self.controllers = {
            name: DensityController(
                gaussians, plan.densify, self.extent, self.optimizer, self.density_generator
            )
            for name, gaussians in self.sets.items()
            if (plan := self.plans[name]).densify is not None
        }
        self.module_optimizer = None
        if self.module_groups:
            groups = [
                {"params": group.params, "name": group.name, "lr": group.schedule.at(0)}
                for group in self.module_groups
            ]
            self.module_optimizer = adam(groups)

    def prepare_step(self, step: int) -> dict[str, float]:
        """Set learning rates and SH degrees for `step`; drop old gradients; returns the lrs."""
        rates = self.optimizer.update_learning_rates(step)
        if self.module_optimizer is not None:
            for group, spec in zip(
                self.module_optimizer.param_groups, self.module_groups, strict=True
            ):
                lr = spec.schedule.at(step) * (self.extent if spec.scale_by_extent else 1.0)
                group["lr"] = lr
                rates[spec.name] = lr
            self.module_optimizer.zero_grad(set_to_none=True)
        for name, gaussians in self.sets.items():
            scheduled = sh_degree_for_step(step, gaussians.max_sh_degree, self.plans[name].sh_every)
            gaussians.active_sh_degree = max(self._base_sh[name], scheduled)
        self.optimizer.zero_grad()
        return rates

    def settle(self) -> None:
        """Bring every row of the row-stepped sets up to date (the end of training)."""
        self.optimizer.settle()

    def parameters(self) -> dict[str, Tensor]:
        """Every trainable tensor by name (`<set>.<param>`, `<module>.<param>`)."""
        named = {f"{s}.{n}": p for s, g in self.sets.items() for n, p in g.params.items()}
        for module_name, module in self.modules.items():
            named.update({f"{module_name}.{n}": p for n, p in module.named_parameters()})
        return named

    def check_finite(self, stage: str, step: int, loss: Tensor | None = None) -> None:
        """DivergenceError naming a non-finite loss or gradient (with `loss`: each step, before
        the update) or parameter (without: before a checkpoint), and the suspects. A parameter
        an update made non-finite shows in the next step's loss or gradients, or here."""
        parameters = self.parameters()
        if loss is None:
            tensors = parameters
        else:
            gradients = {f"{n}.grad": p.grad for n, p in parameters.items() if p.grad is not None}
            gradients.update({f"{n}.grad": g for n, g in self.optimizer.row_gradients().items()})
            tensors = {"loss": loss.detach(), **gradients}
        try:
            check_finite(stage, step, tensors)
        except DivergenceError as error:
            raise DivergenceError(f"{error}; {divergence_suspects(parameters, step)}") from None

    def apply_gradients(self, renders: list[Render], step: int) -> list[DensifyReport]:
        """Optimiser steps, then density statistics from `renders` and density control."""
        self.optimizer.step()
        if self.module_optimizer is not None:
            self.module_optimizer.step()
        reports = []
        for name, controller in self.controllers.items():
            stats = [s for r in renders if (s := screen_statistics(r, name)) is not None]
            if stats:
                meta = renders[0].groups[0][1]  # the training scene has one camera size
                size = int(meta["width"]), int(meta["height"])
                cameras = sum(grad.shape[0] for grad, _, _ in stats)
                # whole-set pieces in one call (one sum over their cameras), row pieces each
                whole = [(grad, radius) for grad, radius, rows in stats if rows is None]
                if whole:
                    grads, radii = (torch.cat(pieces) for pieces in zip(*whole, strict=True))
                    controller.accumulate(grads, radii, *size, cameras=cameras)
                for grad, radius, rows in stats:
                    if rows is not None:
                        controller.accumulate(grad, radius, *size, cameras=cameras, rows=rows)
            report = controller.step(step)
            if report is not None:
                reports.append(report)
        return reports

    def state_tensors(self) -> dict[str, Tensor]:
        """Everything needed to resume, as named tensors (sets, modules, density stats, RNG)."""
        tensors: dict[str, Tensor] = {}
        for name, gaussians in self.sets.items():
            tensors.update(gaussians.to_tensors(f"set.{name}."))
        for name, module in self.modules.items():
            tensors.update({f"module.{name}.{k}": v for k, v in module.state_dict().items()})
        for name, controller in self.controllers.items():
            tensors.update({f"density.{name}.{k}": v for k, v in controller.state_dict().items()})
        for name, row_adam in self.optimizer.row_adams.items():
            row_state = row_adam.state_tensors()
            tensors.update({f"{ROW_ADAM}.{name}.{k}": v for k, v in row_state.items()})
        tensors[GENERATOR_KEY] = self.generator.get_state()
        tensors[DENSITY_GENERATOR_KEY] = self.density_generator.get_state()
        return tensors

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers whose state a checkpoint saves, by name."""
        optimizers: dict[str, torch.optim.Optimizer] = {}
        if self.optimizer.adam is not None:
            optimizers["gaussians"] = self.optimizer.adam
        if self.module_optimizer is not None:
            optimizers["modules"] = self.module_optimizer
        return optimizers

    def restore(self, state: TrainingState) -> None:
        """Resume from a checkpoint written from `state_tensors` / `optimizers`; the sets are
        rebuilt at their saved (densified) shapes before the optimisers load their state."""
        tensors = state.tensors

        def under(prefix: str) -> dict[str, Tensor]:
            return {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}

        for name in self.sets:
            self.sets[name] = GaussianSet.from_tensors(under(f"set.{name}.")).to(self.device)
        for name, module in self.modules.items():
            module.load_state_dict(under(f"module.{name}."))
        self.build()
        for name, row_adam in self.optimizer.row_adams.items():
            try:
                row_adam.load_state_tensors(under(f"{ROW_ADAM}.{name}."))
            except KeyError as error:
                raise InputError(
                    f"checkpoint of step {state.step}: no row-Adam state {error} for set "
                    f"{name!r} (written by an older relaygs); remove the stage's .ckpt folder "
                    "to train it again from step 0"
                ) from None
        if self.optimizer.adam is not None:
            self.optimizer.adam.load_state_dict(state.optimizers["gaussians"])
        if self.module_optimizer is not None:
            self.module_optimizer.load_state_dict(state.optimizers["modules"])
        for name, controller in self.controllers.items():
            controller.load_state_dict(under(f"density.{name}."))
        self.generator.set_state(tensors[GENERATOR_KEY])
        self.density_generator.set_state(tensors[DENSITY_GENERATOR_KEY])
        state.restore_rng()
