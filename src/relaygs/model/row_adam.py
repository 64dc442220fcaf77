"""Adam for a Gaussian set whose steps each show a few of its rows (the relay copies). Dense Adam
steps every row each step, those not shown with a zero gradient: their moments decay and they
keep drifting along them, at the cost of the whole set every step. Here a step gathers the shown
rows, renders from them, steps them with torch's Adam kernel and writes them back; a row's
zero-gradient steps are applied in closed form when it is next read (`select`) or the set is
settled (density control, the end of training): dense Adam's values to rounding, at the cost of
the shown rows."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import torch
from torch import Tensor
from torch.optim.adam import adam as adam_step

from relaygs.model.gaussians import GaussianSet

BETA1, BETA2 = 0.9, 0.999  # torch's Adam defaults, which every optimiser here uses
DRIFT_RATIO = BETA1 / BETA2**0.5  # a zero-gradient step's move shrinks by this each step
# Drift terms summed after a row's last update: DRIFT_RATIO**512 < 1e-23, so later steps move
# a row by less than float32 resolves.
DRIFT_TERMS = 512
LAST_KEY, COUNT_KEY = "last", "count"


@dataclass
class _ParamState:
    """Adam moments of every row of one parameter, and each step's drift rate lr·√(1−β2ⁿ)/(1−β1ⁿ)
    (what a unit m/√v moves a row by at a zero-gradient step n)."""

    exp_avg: Tensor
    exp_avg_sq: Tensor
    rates: list[float]

    def drift(self, since: int, count: int) -> float:
        """How far a row last updated at step `since` has moved by step `count`, per unit m/√v."""
        rates = self.rates[since : min(count, since + DRIFT_TERMS)]
        return sum(rate * DRIFT_RATIO ** (j + 1) for j, rate in enumerate(rates))


@dataclass
class _Read:
    """One read of the set's rows in a step: the rows as passed (compared by identity), their
    distinct values (sorted) and where each read row sits among them, and per parameter the leaf
    the render reads (its .grad the rows' gradient) with the rows' moments."""

    rows: Tensor
    unique: Tensor
    inverse: Tensor
    leaves: dict[str, Tensor]
    moments: dict[str, tuple[Tensor, Tensor]]


class RowAdam:
    """Adam (eps `eps`) over every parameter of `gaussians`, stepped by the rows each step shows.

    Renders read the set's rows through `GaussianSet.select_rows`, which brings them up to date;
    `step()` then updates the rows read (torch's kernel: dense Adam's arithmetic for them), a
    parameter the loss did not reach with a zero gradient. `lr_of(name)`: this step's rate."""

    def __init__(
        self, gaussians: GaussianSet, lr_of: Callable[[str], float], eps: float, fused: bool
    ) -> None:
        self.gaussians = gaussians
        self.eps = eps
        self._lr_of = lr_of
        self._fused = fused
        self.state = {
            name: _ParamState(torch.zeros_like(param), torch.zeros_like(param), [])
            for name, param in gaussians.params.items()
        }
        self.count = 0  # steps taken; row i is up to date to step last[i]
        self.last = torch.zeros(len(gaussians), dtype=torch.int64, device=gaussians.means.device)
        self._reads: list[_Read] = []
        gaussians.row_reader = self

    def select(self, name: str, rows: Tensor) -> Tensor:
        """Rows of parameter `name`, up to date, as the render's input (gradient kept)."""
        read = next((read for read in self._reads if read.rows is rows), None)
        if read is None:
            read = self._read(rows)
            self._reads.append(read)
        return read.leaves[name].index_select(0, read.inverse)

    def gradients(self) -> dict[str, Tensor]:
        """This step's gradients of the rows read, by parameter (for the divergence guard)."""
        grads: dict[str, list[Tensor]] = {}
        for read in self._reads:
            for name, leaf in read.leaves.items():
                if leaf.grad is not None:
                    grads.setdefault(name, []).append(leaf.grad.reshape(-1))
        return {name: torch.cat(pieces) for name, pieces in grads.items()}

    def zero_grad(self) -> None:
        """Drop this step's reads and gradients (a new step begins)."""
        self._reads.clear()

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step: the rows read take their gradients, every other row a zero one
        (applied when it is next read)."""
        self.count += 1
        for name, state in self.state.items():
            n, lr = self.count, self._lr_of(name)
            state.rates.append(lr * (1.0 - BETA2**n) ** 0.5 / (1.0 - BETA1**n))
        if not self._reads:
            return
        if len(self._reads) == 1:
            read = self._reads[0]
            rows = read.unique
            for name, leaf in read.leaves.items():
                exp_avg, exp_avg_sq = read.moments[name]
                grad = leaf.grad if leaf.grad is not None else torch.zeros_like(leaf)
                self._update(name, rows, leaf.detach(), grad, exp_avg, exp_avg_sq)
        else:  # reads that may share rows (two slots of one frame): their gradients add
            rows = torch.unique(torch.cat([read.unique for read in self._reads]))
            places = [torch.searchsorted(rows, read.unique) for read in self._reads]
            for name, param in self.gaussians.params.items():
                state = self.state[name]
                grad = param.new_zeros((rows.shape[0], *param.shape[1:]))
                for read, place in zip(self._reads, places, strict=True):
                    if read.leaves[name].grad is not None:
                        grad.index_add_(0, place, read.leaves[name].grad)
                values = param.detach().index_select(0, rows)
                exp_avg = state.exp_avg.index_select(0, rows)
                exp_avg_sq = state.exp_avg_sq.index_select(0, rows)
                self._update(name, rows, values, grad, exp_avg, exp_avg_sq)
        self.last.index_fill_(0, rows, self.count)
        self._reads.clear()

    @torch.no_grad()
    def settle(self) -> None:
        """Bring every row up to date (before anything reads the whole set); nothing to do, and
        nothing gathered, where every row already is (a second settle in one step)."""
        if bool((self.last == self.count).all()):
            return
        self._catch_up(torch.arange(len(self.last), device=self.last.device))

    @torch.no_grad()
    def reindex(self, index: Tensor, fresh: Tensor | None) -> None:
        """Rows were reindexed (GaussianSet.reindex_rows_ with `index`): the state follows,
        `fresh` rows start with zero moments. The set must be settled first."""
        for state in self.state.values():
            state.exp_avg = state.exp_avg[index]
            state.exp_avg_sq = state.exp_avg_sq[index]
            if fresh is not None:
                state.exp_avg[fresh] = 0.0
                state.exp_avg_sq[fresh] = 0.0
        self.last = torch.full_like(index, self.count)

    def reset(self, name: str) -> None:
        """Zero the moments of parameter `name` (after an opacity reset; the set settled)."""
        self.state[name].exp_avg.zero_()
        self.state[name].exp_avg_sq.zero_()

    def moments(self, name: str) -> dict[str, Tensor]:
        """The Adam moments of parameter `name`, every row."""
        state = self.state[name]
        return {"exp_avg": state.exp_avg, "exp_avg_sq": state.exp_avg_sq}

    def state_tensors(self) -> dict[str, Tensor]:
        """Everything to resume exactly (rows not yet caught up stay so), as named tensors."""
        tensors = {LAST_KEY: self.last, COUNT_KEY: torch.tensor(self.count, dtype=torch.int64)}
        for name, state in self.state.items():
            tensors[f"{name}.exp_avg"] = state.exp_avg
            tensors[f"{name}.exp_avg_sq"] = state.exp_avg_sq
            tensors[f"{name}.rates"] = torch.tensor(state.rates, dtype=torch.float64)
        return tensors

    def load_state_tensors(self, tensors: Mapping[str, Tensor]) -> None:
        """Restore what `state_tensors` saved (KeyError where a tensor is missing)."""
        device = self.last.device
        self.last = tensors[LAST_KEY].to(device, torch.int64).clone()
        self.count = int(tensors[COUNT_KEY])
        for name, param in self.gaussians.params.items():
            state = self.state[name]
            state.exp_avg = tensors[f"{name}.exp_avg"].to(device, param.dtype).clone()
            state.exp_avg_sq = tensors[f"{name}.exp_avg_sq"].to(device, param.dtype).clone()
            state.rates = tensors[f"{name}.rates"].tolist()

    def _read(self, rows: Tensor) -> _Read:
        """Catch up `rows` and gather them as leaves the render differentiates."""
        unique, inverse = torch.unique(rows, return_inverse=True)
        gathered = self._catch_up(unique)
        leaves = {name: values.requires_grad_() for name, (values, _, _) in gathered.items()}
        moments = {name: (m, v) for name, (_, m, v) in gathered.items()}
        return _Read(rows, unique, inverse, leaves, moments)

    @torch.no_grad()
    def _catch_up(self, rows: Tensor) -> dict[str, tuple[Tensor, Tensor, Tensor]]:
        """Apply the zero-gradient steps distinct `rows` missed since their last update, in
        closed form (m and v decay by β1ᵏ and β2ᵏ, the value moves by Σ rate·(β1/√β2)ʲ · m/√v);
        returns each parameter's rows (values, m, v), up to date."""
        last = self.last.index_select(0, rows)
        since = torch.unique(last).tolist()  # a few distinct steps: one per copy read
        gathered = {}
        for name, param in self.gaussians.params.items():
            state = self.state[name]
            gathered[name] = (
                param.detach().index_select(0, rows),
                state.exp_avg.index_select(0, rows),
                state.exp_avg_sq.index_select(0, rows),
            )
        if since in ([], [self.count]):
            return gathered
        place = torch.searchsorted(torch.tensor(since, device=last.device), last)
        behind = (self.count - last).to(torch.float32)
        decay = {BETA1: torch.pow(BETA1, behind), BETA2: torch.pow(BETA2, behind)}
        for name, (values, exp_avg, exp_avg_sq) in gathered.items():
            state = self.state[name]
            shape = (-1,) + (1,) * (values.dim() - 1)
            table = torch.tensor([state.drift(s, self.count) for s in since], dtype=torch.float64)
            moves = table.to(values.device, values.dtype)[place].view(shape)
            # eps keeps the quotient finite where v underflowed to 0 (dense Adam adds it too)
            values -= moves * exp_avg / (exp_avg_sq.sqrt() + self.eps)
            exp_avg *= decay[BETA1].view(shape)
            exp_avg_sq *= decay[BETA2].view(shape)
            self.gaussians.params[name].index_copy_(0, rows, values)
            state.exp_avg.index_copy_(0, rows, exp_avg)
            state.exp_avg_sq.index_copy_(0, rows, exp_avg_sq)
        self.last.index_fill_(0, rows, self.count)
        return gathered

    def _update(
        self,
        name: str,
        rows: Tensor,
        values: Tensor,
        grad: Tensor,
        exp_avg: Tensor,
        exp_avg_sq: Tensor,
    ) -> None:
        """Torch's Adam step `count` on gathered rows, written back to the parameter and state."""
        step_device = values.device if self._fused else torch.device("cpu")
        state_step = torch.tensor(float(self.count - 1), dtype=torch.float32, device=step_device)
        adam_step(
            [values],
            [grad],
            [exp_avg],
            [exp_avg_sq],
            [],
            [state_step],
            foreach=not self._fused,
            fused=self._fused,
            amsgrad=False,
            beta1=BETA1,
            beta2=BETA2,
            lr=self._lr_of(name),
            weight_decay=0.0,
            eps=self.eps,
            maximize=False,
        )
        state = self.state[name]
        self.gaussians.params[name].index_copy_(0, rows, values)
        state.exp_avg.index_copy_(0, rows, exp_avg)
        state.exp_avg_sq.index_copy_(0, rows, exp_avg_sq)
