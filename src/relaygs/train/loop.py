"""The training loop every stage shares, with divergence guard, logging and checkpoints."""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

import torch
from torch import Tensor

from relaygs.errors import Interrupted
from relaygs.pipeline.checkpoint import StageCheckpointer
from relaygs.pipeline.context import current_build
from relaygs.progress import print_labelled, progress_bar
from relaygs.train import log
from relaygs.train.loss import batch_psnr
from relaygs.train.render import Render
from relaygs.train.session import TrainingSession

LOSS_WINDOW = 50  # steps averaged for the initial and final loss (at most a quarter of the run)


@dataclass
class StepResult:
    """One forward pass: loss, renders (density statistics), predicted and target images."""

    loss: Tensor
    renders: list[Render]
    preds: list[Tensor]
    targets: list[Tensor]


@dataclass
class TrainReport:
    """Summary of a training run; `train_seconds` includes those before a resume."""

    steps: int
    initial_loss: float | None  # None when the stage ran no steps
    final_loss: float | None
    train_seconds: float
    run_seconds: float
    resumed_from: int
    history: list[ScalarRecord] = field(default_factory=list)

    def metrics(self) -> dict[str, float | int | None]:
        return {
            "steps": self.steps,
            "initial_loss": self.initial_loss,
            "final_loss": self.final_loss,
            "train_seconds": self.train_seconds,
            "steps_per_second": (self.steps - self.resumed_from) / max(self.run_seconds, 1e-9),
            "resumed_from": self.resumed_from,
        }


class LossTracker:
    """Mean loss of the first and latest `window` steps, as tensors until read (no GPU sync)."""

    def __init__(self, window: int) -> None:
        self.window = window
        self.first: list[float | Tensor] = []
        self.recent: deque[float | Tensor] = deque(maxlen=window)

    def add(self, loss: Tensor) -> None:
        loss = loss.detach()
        if len(self.first) < self.window:
            self.first.append(loss)
        self.recent.append(loss)

    def state(self) -> dict[str, list[float]]:
        """JSON-ready state for checkpoints (one read from the device)."""
        first, recent = _floats(self.first, list(self.recent))
        return {"first": first, "recent": recent}

    def means(self) -> tuple[float | None, float | None]:
        """Mean loss of the first and of the latest window (None for no steps)."""
        first, recent = _floats(self.first, list(self.recent))
        return _mean(first), _mean(recent)

    def load_state(self, state: dict) -> None:
        self.first = list(state["first"])
        self.recent.clear()
        self.recent.extend(state["recent"])


class LoopSettings(Protocol):
    """What the loop reads of the stages' `TrainSettings` (declared here: stages import this)."""

    @property
    def log_every(self) -> int: ...
    @property
    def image_every(self) -> int: ...
    @property
    def checkpoint_every(self) -> int: ...
    @property
    def progress(self) -> bool: ...


ScalarRecord = tuple[int, dict[str, float]]  # one emitted record's step and scalars


class ScalarHistory:
    """A stage's finite scalar records, kept in its meta and checkpoints for reruns' curves."""

    def __init__(self) -> None:
        self.records: list[ScalarRecord] = []

    def add(self, step: int, scalars: Mapping[str, float]) -> None:
        finite = {name: float(value) for name, value in scalars.items() if math.isfinite(value)}
        self.records.append((step, finite))

    def state(self) -> list[list]:
        """JSON-ready state (for checkpoints and artifact meta): `[[step, {name: value}], ...]`."""
        return [[step, dict(scalars)] for step, scalars in self.records]

    def load_state(self, state: list[list]) -> None:
        self.records = [(int(step), dict(scalars)) for step, scalars in state]


CountsFn = Callable[[], tuple[int, int]]


def run_training(
    stage: str,
    session: TrainingSession,
    steps: int,
    train: LoopSettings,
    step_fn: Callable[[int], StepResult],
    counts: CountsFn,
) -> TrainReport:
    """Run steps 1..`steps` of `step_fn` on `session`, resuming from a checkpoint if present;
    DivergenceError at the first non-finite value. `counts()`: (bg, fg) counts to log."""
    build = current_build()
    checkpointer = build.checkpointer(train.checkpoint_every) if build is not None else None
    tracker = LossTracker(max(1, min(LOSS_WINDOW, steps // 4)))
    history = ScalarHistory()
    start, previous_seconds = 0, 0.0
    state = checkpointer.load() if checkpointer is not None else None
    if state is not None:
        session.restore(state)
        start = state.step
        tracker.load_state(state.extras["losses"])
        history.load_state(state.extras.get("history", []))  # older checkpoints have none
        previous_seconds = float(state.extras["seconds"])
        build.earlier_seconds = previous_seconds  # a checkpoint was found: `build` is set
        for step, scalars in history.records:  # this run's sinks see the steps before the kill
            log.emit(stage, step, scalars)
        print_labelled(
            f"[{stage}] resuming from the checkpoint of step {start} of {steps} "
            f"({previous_seconds:.1f} s of training before it)"
        )
    began = time.perf_counter()
    bar = progress_bar(
        total=steps, initial=start, desc=stage, disable=not train.progress, leave=False
    )

    def train_step(step: int) -> None:
        rates = session.prepare_step(step)
        result = step_fn(step)
        if result.loss.requires_grad:  # False only when nothing trainable was rendered
            result.loss.backward()
        session.check_finite(stage, step, result.loss)
        session.apply_gradients(result.renders, step)
        tracker.add(result.loss)
        images = None
        if train.image_every > 0 and step % train.image_every == 0:
            images = {
                "render": result.preds[0].detach().clamp(0.0, 1.0).cpu(),
                "target": result.targets[0].detach().cpu(),
            }
        if step % train.log_every == 0 or step == steps or images is not None:
            loss = float(result.loss.detach())
            n_bg, n_fg = counts()
            scalars = {
                "loss": loss,
                "psnr": batch_psnr(result.preds, result.targets),
                "num_bg": float(n_bg),
                "num_fg": float(n_fg),
                "fg_fraction": n_fg / max(n_bg + n_fg, 1),
                **{f"lr/{name}": lr for name, lr in rates.items()},
            }
            history.add(step, scalars)
            log.emit(stage, step, scalars, images)
            bar.set_postfix(loss=f"{loss:.4f}", psnr=f"{scalars['psnr']:.2f}", refresh=False)
        if checkpointer is not None and checkpointer.due(step):
            session.check_finite(stage, step)  # the optimiser step must not reach the disk
            seconds = previous_seconds + time.perf_counter() - began
            checkpointer.save(
                step,
                session.state_tensors(),
                session.optimizers(),
                {"losses": tracker.state(), "seconds": seconds, "history": history.state()},
            )
        bar.update(1)

    done = start  # steps completed, for the Ctrl-C message (a disabled bar does not count)
    try:
        with bar:
            for step in range(start + 1, steps + 1):
                train_step(step)
                done = step
    except KeyboardInterrupt:
        raise _interrupted(stage, done, steps, checkpointer) from None
    session.settle()
    session.check_finite(stage, steps)
    run_seconds = time.perf_counter() - began
    initial_loss, final_loss = tracker.means()
    return TrainReport(
        steps=steps,
        initial_loss=initial_loss,
        final_loss=final_loss,
        train_seconds=previous_seconds + run_seconds,
        run_seconds=run_seconds,
        resumed_from=start,
        history=history.records,
    )


def _interrupted(
    stage: str, done: int, steps: int, checkpointer: StageCheckpointer | None
) -> Interrupted:
    """What Ctrl-C stopped and what running the same command again resumes from."""
    where = f"{stage} stopped after step {done} of {steps}"
    if checkpointer is None:
        return Interrupted(f"{where} (not run through the artifact store: nothing to resume)")
    last = checkpointer.latest_due(done)
    if last == 0:
        return Interrupted(
            f"{where}; no in-stage checkpoint yet "
            f"(train.checkpoint_every={checkpointer.every_n_steps}): the same "
            "command starts this stage over, finished stages are reused"
        )
    return Interrupted(
        f"{where}; run the same command again to resume it from its checkpoint of step {last}"
    )


def _floats(*lists: list[float | Tensor]) -> list[list[float]]:
    """The lists with their tensors read as floats, all in one read from the device."""
    tensors = [value for values in lists for value in values if isinstance(value, Tensor)]
    read = iter(torch.stack(tensors).tolist() if tensors else [])
    return [
        [next(read) if isinstance(value, Tensor) else value for value in values] for values in lists
    ]


def _mean(values: list[float]) -> float | None:
    """The mean, or None for no values (JSON has no NaN, and a stage may run 0 steps)."""
    return sum(values) / len(values) if values else None
