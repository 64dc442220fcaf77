"""Optimiser groups and schedules: log-linear lr, fg/bg position step sizes, Adam row remaps."""

import pytest
import torch

from relaygs.errors import InputError
from relaygs.model import (
    GaussianOptimizer,
    GaussianSet,
    LRSchedule,
    SetLearningRates,
    log_linear,
    optim,
)


def make_set(n: int, seed: int) -> GaussianSet:
    gen = torch.Generator().manual_seed(seed)
    return GaussianSet.from_points(torch.rand(n, 3, generator=gen), torch.rand(n, 3, generator=gen))


def test_log_linear_endpoints_midpoint_and_delay() -> None:
    assert log_linear(1e-3, 1e-5, 0, 100) == pytest.approx(1e-3)
    assert log_linear(1e-3, 1e-5, 100, 100) == pytest.approx(1e-5)
    assert log_linear(1e-3, 1e-5, 500, 100) == pytest.approx(1e-5)
    assert log_linear(1e-3, 1e-5, 50, 100) == pytest.approx(1e-4)
    assert log_linear(1e-3, 1e-5, 0, 100, delay_steps=10, delay_mult=0.01) == pytest.approx(1e-5)
    assert log_linear(1e-3, 1e-5, 10, 100, delay_steps=10, delay_mult=0.01) == pytest.approx(
        1e-3 * (1e-2) ** 0.1
    )
    assert log_linear(1e-3, 1e-5, 7, 0) == pytest.approx(1e-5)
    assert log_linear(0.0, 0.0, 7, 10) == 0.0
    assert log_linear(1e-3, 1e-5, -1, 100) == 0.0  # before the first step
    assert log_linear(1e-3, 1e-5, -1, 100, delay_steps=10, delay_mult=0.5) == 0.0
    with pytest.raises(InputError, match="lr_init"):
        log_linear(1e-3, 0.0, 1, 10)


def test_fg_and_bg_position_steps_follow_their_own_rates() -> None:
    fg, bg = make_set(5, 0), make_set(7, 1)
    fg_before, bg_before = fg.means.detach().clone(), bg.means.detach().clone()
    rates = {
        "fg": SetLearningRates(means=LRSchedule(1e-3)),
        "bg": SetLearningRates(means=LRSchedule(2e-4, 1e-5, 1000)),
    }
    optimizer = GaussianOptimizer({"fg": fg, "bg": bg}, rates, spatial_lr_scale=2.0)
    (fg.means.sum() - bg.means.sum() * 3.0).backward()
    optimizer.adam.step()
    fg_step = (fg.means.detach() - fg_before).abs()
    bg_step = (bg.means.detach() - bg_before).abs()
    assert torch.allclose(fg_step, torch.full_like(fg_step, 2e-3), rtol=1e-3)
    assert torch.allclose(bg_step, torch.full_like(bg_step, 4e-4), rtol=1e-3)
    assert optimizer.update_learning_rates(0)["bg.log_scales"] == pytest.approx(5e-3)
    rates_later = optimizer.update_learning_rates(1000)
    assert rates_later["bg.means"] == pytest.approx(2e-5)
    assert rates_later["fg.means"] == pytest.approx(2e-3)


def test_extras_get_their_own_group_and_must_have_a_schedule() -> None:
    g = make_set(4, 2)
    g.add_param("gamma", torch.zeros(4, 3))
    with pytest.raises(InputError, match="gamma"):
        GaussianOptimizer({"fg": g}, {"fg": SetLearningRates()})
    rates = SetLearningRates.from_config(
        {"means": {"init": 1e-3}, "sh_dc": 0.01, "extras": {"gamma": 1e-4}}
    )
    optimizer = GaussianOptimizer({"fg": g}, {"fg": rates})
    rates_now = optimizer.update_learning_rates(0)
    assert rates_now["fg.gamma"] == pytest.approx(1e-4)
    assert rates_now["fg.sh_dc"] == pytest.approx(0.01)
    assert optimizer.adam.defaults["eps"] == 1e-15
    with pytest.raises(InputError, match="bogus"):
        SetLearningRates.from_config({"bogus": 1.0})


def test_reindex_rows_moves_adam_state_with_rows() -> None:
    g = make_set(4, 3)
    g.add_buffer("segment", torch.tensor([10, 11, 12, 13]))
    optimizer = GaussianOptimizer({"bg": g}, {"bg": SetLearningRates()})
    weights = torch.arange(1.0, 5.0)
    (g.params["opacity_logits"] * weights).sum().backward()
    optimizer.adam.step()
    old_avg = optimizer.state_of(g.params["opacity_logits"])["exp_avg"].clone()
    fresh = torch.tensor([False, False, True])
    optimizer.reindex_rows(g, torch.tensor([3, 1, 1]), fresh)
    new_state = optimizer.state_of(g.params["opacity_logits"])
    expected_avg = torch.stack([old_avg[3], old_avg[1], old_avg.new_zeros(())])
    assert torch.equal(new_state["exp_avg"], expected_avg)
    assert torch.equal(g.buffers["segment"], torch.tensor([13, 11, 11]))
    groups = {group["name"]: group["params"][0] for group in optimizer.adam.param_groups}
    assert groups["bg.opacity_logits"] is g.params["opacity_logits"]
    before = g.params["opacity_logits"].detach().clone()
    g.params["opacity_logits"].sum().backward()
    optimizer.adam.step()
    assert not torch.equal(before, g.params["opacity_logits"].detach())


def _three_steps(optimizer_factory) -> torch.Tensor:
    """A parameter after three Adam steps on a fixed quadratic, from a fixed start."""
    param = torch.nn.Parameter(torch.linspace(-1.0, 2.0, 7))
    optimizer = optimizer_factory([{"params": [param], "lr": 0.0}])
    for group in optimizer.param_groups:
        group["lr"] = 0.1
    for _ in range(3):
        optimizer.zero_grad()
        (param**2 * torch.arange(1.0, 8.0)).sum().backward()
        optimizer.step()
    return param.detach()


def test_adam_takes_the_foreach_step_where_torch_has_no_fused_kernel(monkeypatch) -> None:
    # torch < 2.4 refuses fused=True on the CPU when the optimiser is built
    fused = _three_steps(optim.adam)
    built = []

    class AdamWithoutFused(torch.optim.Adam):
        def __init__(self, params, **options):
            if options.get("fused"):
                raise RuntimeError("`fused=True` requires all the params to be on cuda")
            built.append(options)
            super().__init__(params, **options)

    monkeypatch.setattr(torch.optim, "Adam", AdamWithoutFused)
    optim.has_fused_adam.cache_clear()
    try:
        fallback = _three_steps(optim.adam)
        assert not optim.has_fused_adam(torch.device("cpu"))
    finally:
        optim.has_fused_adam.cache_clear()
    assert built and built[-1]["foreach"] is True
    torch.testing.assert_close(fallback, fused, rtol=1e-6, atol=1e-7)
    assert not torch.equal(fallback, torch.linspace(-1.0, 2.0, 7))


@pytest.mark.skipif(
    tuple(int(part) for part in torch.__version__.split(".")[:2]) < (2, 4),
    reason="torch < 2.4 has no fused Adam on the CPU",
)
def test_adam_takes_the_fused_step_on_the_cpu_where_torch_has_one() -> None:
    param = torch.nn.Parameter(torch.zeros(3))
    assert optim.adam([{"params": [param]}]).defaults["fused"] is True
    assert not optim.has_fused_adam(torch.device("meta"))
