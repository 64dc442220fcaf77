"""Row-stepped Adam (model.row_adam): the relay copies' optimiser matches dense Adam, which steps
every row every step, while a step touches only the rows it shows."""

from __future__ import annotations

import pytest
import torch

from refusals import refused
from relaygs.errors import DivergenceError, InputError
from relaygs.model import CORE_PARAMS, GaussianOptimizer, GaussianSet, LRSchedule, SetLearningRates
from relaygs.pipeline.checkpoint import TrainingState
from relaygs.train.session import SetPlan, TrainingSession

COPIES = 6
ROWS_PER_COPY = 20
RATES = SetLearningRates(means=LRSchedule(1e-2, 1e-4, 200), sh_dc=LRSchedule(2e-2))


def copies_set(seed: int = 0) -> GaussianSet:
    gen = torch.Generator().manual_seed(seed)
    n = COPIES * ROWS_PER_COPY
    g = GaussianSet.from_points(torch.randn(n, 3, generator=gen), torch.rand(n, 3, generator=gen))
    g.params["sh_rest"].data.normal_(0.0, 0.1, generator=gen)
    return g


def shown_rows(step: int, gen: torch.Generator) -> torch.Tensor:
    """One or two copies a step, sometimes the same copy twice (as relay can draw it)."""
    copies = torch.randint(COPIES, (1 + step % 2,), generator=gen)
    if step % 7 == 0:
        copies = torch.cat([copies, copies[:1]])
    return torch.cat([torch.arange(ROWS_PER_COPY) + int(c) * ROWS_PER_COPY for c in copies])


def loss_of(g: GaussianSet, rows: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    loss = torch.zeros(())
    for name in CORE_PARAMS:
        values = g.select_rows(name, rows)
        goal = target[rows] if name == "means" else torch.full_like(values, 0.2)
        loss = loss + ((values - goal) ** 2).sum()
    return loss


def train(g: GaussianSet, by_rows: bool, steps: int, edit_at: int | None = None) -> None:
    """`steps` steps of a per-copy loss; at `edit_at`, a densify-like reindex of the rows."""
    optimizer = GaussianOptimizer({"fg": g}, {"fg": RATES}, 2.0, row_sets=["fg"] if by_rows else [])
    gen = torch.Generator().manual_seed(3)
    target = torch.randn(len(g), 3, generator=torch.Generator().manual_seed(4))
    for step in range(1, steps + 1):
        optimizer.update_learning_rates(step)
        optimizer.zero_grad()
        rows = shown_rows(step, gen)
        loss_of(g, rows, target).backward()
        optimizer.step()
        if step == edit_at:  # prune the last 7 rows, clone the first 7 (fresh moments)
            source = torch.cat([torch.arange(len(g) - 7), torch.arange(7)])
            fresh = torch.arange(len(g)) >= len(g) - 7
            optimizer.reindex_rows(g, source, fresh)
            target = target[source]
    optimizer.settle()


@pytest.mark.parametrize("edit_at", [None, 60])
def test_row_stepped_copies_match_dense_adam(edit_at: int | None) -> None:
    """Unshown rows keep drifting on their momentum as under dense Adam; moments and a reindex
    (density control) follow the rows."""
    dense, rows = copies_set(), copies_set()
    train(dense, by_rows=False, steps=150, edit_at=edit_at)
    train(rows, by_rows=True, steps=150, edit_at=edit_at)
    for name in CORE_PARAMS:
        expected, got = dense.params[name].detach(), rows.params[name].detach()
        assert got.shape == expected.shape
        assert torch.allclose(got, expected, rtol=1e-4, atol=2e-5), name
        assert not torch.equal(got, copies_set().params[name].detach()[: len(got)]), name


def test_a_row_stepped_set_gets_no_whole_set_gradient_and_every_row_shown_is_exact() -> None:
    """Where every row is shown every step there is no catch-up: bitwise dense Adam."""
    dense, rows = copies_set(), copies_set()
    target = torch.randn(len(dense), 3, generator=torch.Generator().manual_seed(5))
    everything = torch.arange(len(dense))
    for g, row_sets in ((dense, []), (rows, ["fg"])):
        optimizer = GaussianOptimizer({"fg": g}, {"fg": RATES}, 1.0, row_sets=row_sets)
        for step in range(1, 6):
            optimizer.update_learning_rates(step)
            optimizer.zero_grad()
            loss_of(g, everything, target).backward()
            if row_sets:
                assert all(p.grad is None for p in g.params.values())
                assert set(optimizer.row_gradients()) == {f"fg.{n}" for n in CORE_PARAMS}
            optimizer.step()
    for name in CORE_PARAMS:
        assert torch.equal(rows.params[name], dense.params[name]), name


def test_a_non_finite_row_gradient_stops_the_step_naming_it() -> None:
    g = copies_set()
    plan = SetPlan(RATES, None, by_rows=True)
    session = TrainingSession({"fg": g}, {"fg": plan}, 1.0, 0, torch.device("cpu"))
    session.prepare_step(1)
    values = g.select_rows("opacity_logits", torch.arange(5))
    (values * torch.tensor([1.0, 1.0, float("nan"), 1.0, 1.0])).sum().backward()
    with refused(DivergenceError, "'relay'", "step 1", "fg.opacity_logits.grad"):
        session.check_finite("relay", 1, torch.zeros(()))


def test_a_checkpoint_without_row_state_is_refused_naming_the_set() -> None:
    """A checkpoint written before the copies were stepped by rows (one dense Adam over both
    sets) cannot resume them: one line, not torch's group-count error."""
    sets = {"bg": copies_set(1), "fg": copies_set(2)}
    plans = {"bg": SetPlan(RATES, None), "fg": SetPlan(RATES, None, by_rows=True)}
    session = TrainingSession(sets, plans, 1.0, 0, torch.device("cpu"))
    tensors = {k: v for k, v in session.state_tensors().items() if not k.startswith("row_adam.")}
    dense = GaussianOptimizer(sets, {"bg": RATES, "fg": RATES})
    state = TrainingState(7, tensors, {"gaussians": dense.adam.state_dict()}, {})
    with refused(InputError, "step 7", "'fg'"):
        session.restore(state)
