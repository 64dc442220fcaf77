"""Adaptive density control: grad statistics, clone/split/prune keep rows aligned, reset, cap."""

import math

import torch

from relaygs.model import (
    DensifySettings,
    DensityController,
    GaussianOptimizer,
    GaussianSet,
    LRSchedule,
    SetLearningRates,
)
from relaygs.splat.projection import quat_to_rotmat

SMALL_LOG_SCALE = math.log(1e-3)  # below percent_dense · extent = 0.01 → clone
LARGE_LOG_SCALE = math.log(5e-2)  # above it → split


def make_set(log_scales: list[float], seed: int = 0) -> GaussianSet:
    n = len(log_scales)
    gen = torch.Generator().manual_seed(seed)
    g = GaussianSet.from_points(torch.rand(n, 3, generator=gen), torch.rand(n, 3, generator=gen))
    with torch.no_grad():
        g.params["log_scales"].copy_(torch.tensor(log_scales)[:, None].expand(n, 3))
        g.params["quats"].copy_(torch.randn(n, 4, generator=gen))
        g.params["opacity_logits"].copy_(torch.linspace(-1.0, 1.0, n))
    g.add_param("gamma", torch.randn(n, 3, generator=gen))
    g.add_buffer("segment", torch.arange(n, dtype=torch.int32) * 10)
    return g


def trained(g: GaussianSet) -> GaussianOptimizer:
    """An optimiser over `g` after one step with distinct gradients per row."""
    rates = SetLearningRates(extras={"gamma": LRSchedule(1e-3)})
    optimizer = GaussianOptimizer({"bg": g}, {"bg": rates})
    loss = sum((p * torch.randn_like(p)).sum() for p in g.params.values())
    loss.backward()
    optimizer.adam.step()
    return optimizer


def feed(controller: DensityController, grad_norms: list[float]) -> None:
    """One camera, W = H = 2 so the NDC scale is 1: the accumulated norm is grad_norms."""
    grad = torch.zeros(1, len(grad_norms), 2)
    grad[0, :, 0] = torch.tensor(grad_norms)
    controller.accumulate(grad, torch.ones(1, len(grad_norms), 2, dtype=torch.int32), 2, 2)


def rows_of(g: GaussianSet, optimizer: GaussianOptimizer) -> dict[str, torch.Tensor]:
    out = {name: p.detach().clone() for name, p in g.params.items()}
    out |= {f"avg.{name}": optimizer.state_of(p)["exp_avg"].clone() for name, p in g.params.items()}
    return out | {f"buf.{name}": b.clone() for name, b in g.buffers.items()}


def test_accumulate_scales_to_ndc_and_counts_visible_views() -> None:
    g = make_set([SMALL_LOG_SCALE] * 3)
    controller = DensityController(g, DensifySettings(), 1.0)
    grad = torch.zeros(2, 3, 2)
    grad[0, 0] = torch.tensor([1e-4, 0.0])
    grad[1, 0] = torch.tensor([0.0, 1e-4])
    grad[:, 1] = torch.tensor([1e-4, 0.0])
    radii = torch.ones(2, 3, 2, dtype=torch.int32)
    radii[1, 1] = torch.tensor([3, 0])  # one axis culled → invisible in camera 1
    radii[:, 2] = 0
    controller.accumulate(grad, radii, 160, 90)
    expected = torch.tensor([(1e-4 * 80 * 2 + 1e-4 * 45 * 2) / 2, 1e-4 * 80 * 2, 0.0])
    assert torch.allclose(controller.mean_grads(), expected)


def test_accumulate_of_shown_rows_matches_the_scattered_whole_set() -> None:
    gen = torch.Generator().manual_seed(3)
    grad = torch.randn(2, 3, 2, generator=gen) * 1e-4
    radii = torch.randint(0, 3, (2, 3, 2), generator=gen, dtype=torch.int32)
    rows = torch.tensor([4, 0, 2])
    full_grad, full_radii = torch.zeros(4, 5, 2), torch.zeros(4, 5, 2, dtype=torch.int32)
    full_grad[:2, rows], full_radii[:2, rows] = grad, radii
    by_rows = DensityController(make_set([SMALL_LOG_SCALE] * 5), DensifySettings(), 1.0)
    whole = DensityController(make_set([SMALL_LOG_SCALE] * 5), DensifySettings(), 1.0)
    by_rows.accumulate(grad, radii, 160, 90, cameras=4, rows=rows)
    whole.accumulate(full_grad, full_radii, 160, 90)
    torch.testing.assert_close(by_rows.mean_grads(), whole.mean_grads())
    assert torch.equal(by_rows._views, whole._views)
    assert torch.equal(by_rows._max_radii, whole._max_radii)
    assert by_rows._views.sum() > 0 and by_rows._max_radii[1] == by_rows._max_radii[3] == 0


def test_accumulate_of_repeated_rows_equals_one_call_per_repeat() -> None:
    """A copy drawn twice in a step arrives as repeated rows, each seen by other cameras."""
    gen = torch.Generator().manual_seed(4)
    grad = torch.randn(2, 4, 2, generator=gen) * 1e-4
    radii = torch.tensor([[[2, 2], [0, 0], [5, 4], [0, 0]], [[0, 0], [3, 1], [0, 0], [1, 1]]])
    rows = torch.tensor([1, 3, 1, 3])  # rows 1 and 3 twice, at columns 0/2 and 1/3
    once = DensityController(make_set([SMALL_LOG_SCALE] * 4), DensifySettings(), 1.0)
    twice = DensityController(make_set([SMALL_LOG_SCALE] * 4), DensifySettings(), 1.0)
    once.accumulate(grad, radii.int(), 160, 90, cameras=2, rows=rows)
    for half in (slice(0, 2), slice(2, 4)):
        twice.accumulate(grad[:, half], radii[:, half].int(), 160, 90, cameras=2, rows=rows[half])
    torch.testing.assert_close(once._grad_sum, twice._grad_sum)
    assert torch.equal(once._views, twice._views)
    assert torch.equal(once._max_radii, twice._max_radii)
    assert once._max_radii.tolist() == [0.0, 5.0, 0.0, 3.0]


def test_clone_appends_exact_copies_with_copied_adam_rows() -> None:
    g = make_set([SMALL_LOG_SCALE] * 4)
    optimizer = trained(g)
    before = rows_of(g, optimizer)
    controller = DensityController(g, DensifySettings(), 1.0, optimizer)
    feed(controller, [0.0, 1e-3, 1e-5, 3e-4])
    assert controller.densify() == (2, 0)
    after = rows_of(g, optimizer)
    assert len(g) == 6
    for key, value in before.items():
        assert torch.equal(after[key], value[[0, 1, 2, 3, 1, 3]]), key


def test_split_replaces_parent_by_two_rotated_children_with_fresh_state() -> None:
    g = make_set([SMALL_LOG_SCALE, SMALL_LOG_SCALE, LARGE_LOG_SCALE])
    with torch.no_grad():
        g.params["log_scales"][2] = torch.tensor([LARGE_LOG_SCALE, -14.0, -14.0])
    optimizer = trained(g)
    before = rows_of(g, optimizer)
    controller = DensityController(
        g, DensifySettings(), 1.0, optimizer, generator=torch.Generator().manual_seed(0)
    )
    feed(controller, [0.0, 0.0, 1e-3])
    assert controller.densify() == (0, 1)
    after = rows_of(g, optimizer)
    assert len(g) == 4
    for key, value in before.items():
        assert torch.equal(after[key][:2], value[:2]), key
        if key.startswith("avg."):
            assert not after[key][2:].any(), key
        elif key not in ("means", "log_scales"):
            assert torch.equal(after[key][2:], value[[2, 2]]), key
    assert torch.allclose(after["log_scales"][2:], before["log_scales"][[2, 2]] - math.log(1.6))
    long_axis = quat_to_rotmat(g.quats[2].detach())[:, 0]
    for child in (2, 3):
        offset = after["means"][child] - before["means"][2]
        assert offset.norm() > 1e-4
        cosine = torch.dot(offset, long_axis).abs() / offset.norm()
        assert cosine > 0.999


def test_prune_removes_rows_and_shifts_adam_state() -> None:
    g = make_set([SMALL_LOG_SCALE] * 5)
    with torch.no_grad():
        g.params["opacity_logits"][[1, 3]] = -8.0  # sigmoid ≈ 3e-4 < 0.005
    optimizer = trained(g)
    before = rows_of(g, optimizer)
    controller = DensityController(g, DensifySettings(), 1.0, optimizer)
    assert controller.prune() == 2
    after = rows_of(g, optimizer)
    for key, value in before.items():
        assert torch.equal(after[key], value[[0, 2, 4]]), key
    assert torch.equal(after["avg.means"][1], before["avg.means"][2])


def test_opacity_reset_caps_opacity_and_zeroes_its_moments() -> None:
    g = make_set([SMALL_LOG_SCALE] * 3)
    optimizer = trained(g)
    with torch.no_grad():
        g.params["opacity_logits"].copy_(torch.logit(torch.tensor([0.5, 0.001, 0.9])))
    means_avg = optimizer.state_of(g.means)["exp_avg"].clone()
    DensityController(g, DensifySettings(), 1.0, optimizer).reset_opacity()
    assert torch.allclose(g.opacities, torch.tensor([0.01, 0.001, 0.01]), rtol=1e-4)
    assert not optimizer.state_of(g.params["opacity_logits"])["exp_avg_sq"].any()
    assert torch.equal(optimizer.state_of(g.means)["exp_avg"], means_avg)


def test_cap_densifies_only_the_highest_gradients() -> None:
    g = make_set([SMALL_LOG_SCALE] * 10)
    optimizer = trained(g)
    before = rows_of(g, optimizer)
    controller = DensityController(g, DensifySettings(max_gaussians=13), 1.0, optimizer)
    grads = [5e-4, 9e-4, 3e-4, 8e-4, 1e-5, 6e-4, 7e-4, 4e-4, 2e-5, 3.5e-4]
    feed(controller, grads)
    assert controller.densify() == (3, 0)
    assert len(g) == 13
    assert torch.equal(g.means.detach()[10:], before["means"][[1, 3, 6]])


def test_schedule_and_size_pruning_after_first_reset() -> None:
    g = make_set([SMALL_LOG_SCALE] * 3 + [math.log(0.5)])
    settings = DensifySettings(
        densify_from=4, densify_every=2, densify_until=20, opacity_reset_every=10
    )
    controller = DensityController(g, settings, 1.0)
    feed(controller, [1e-3, 0.0, 0.0, 0.0])
    # 3DGS densifies once step > densify_from: step 4, a densify step, is not one yet
    assert controller.step(4) is None and controller.step(7) is None
    report = controller.step(6)
    assert (report.cloned, report.split, report.pruned, report.total) == (1, 0, 0, 5)
    assert not report.opacity_reset
    assert controller.step(8).total == 5  # the large one survives until the first reset
    report = controller.step(10)
    assert report.opacity_reset and report.pruned == 0
    report = controller.step(12)
    assert report.pruned == 1 and len(g) == 4
    assert controller.step(20) is None


def test_size_pruning_from_the_first_densification_when_resets_are_off() -> None:
    g = make_set([SMALL_LOG_SCALE] * 3 + [math.log(0.5)])
    settings = DensifySettings(
        densify_from=0, densify_every=2, densify_until=20, opacity_reset_every=0
    )
    report = DensityController(g, settings, 1.0).step(2)
    assert report.pruned == 1 and not report.opacity_reset and len(g) == 3


def test_screen_radius_pruning_uses_the_largest_radius_seen() -> None:
    # only with size limits; the statistic is the running maximum (the first step's 30 px),
    # not the last step's radius, and a radius at the limit (20) is kept
    g = make_set([SMALL_LOG_SCALE] * 3)
    controller = DensityController(g, DensifySettings(max_screen_radius=20.0), 1.0)
    for radii in ([[30, 2], [5, 5], [19, 20]], [[5, 5], [3, 3], [2, 2]]):
        controller.accumulate(torch.zeros(1, 3, 2), torch.tensor([radii], dtype=torch.int32), 9, 9)
    means = g.means.detach().clone()
    assert controller.prune(size_limits=False) == 0
    assert controller.prune(size_limits=True) == 1
    assert torch.equal(g.means.detach(), means[[1, 2]])
