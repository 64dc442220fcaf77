"""GaussianSet: activations under extreme values, point-cloud init, row ops, tensor round trip."""

import math

import pytest
import torch

from relaygs.errors import InputError
from relaygs.model import MAX_LOG_SCALE, SH_C0, GaussianSet, mean_sq_knn_distance
from relaygs.model import gaussians as gaussians_module
from relaygs.model.gaussians import inverse_sigmoid, normalize_quats, sh_degree_for_step


def random_set(n: int = 6, seed: int = 0) -> GaussianSet:
    gen = torch.Generator().manual_seed(seed)
    return GaussianSet.from_points(torch.rand(n, 3, generator=gen), torch.rand(n, 3, generator=gen))


def with_extras(gaussians: GaussianSet) -> GaussianSet:
    n = len(gaussians)
    gaussians.add_param("gamma", torch.arange(3 * n, dtype=torch.float32).reshape(n, 3))
    gaussians.add_buffer("is_fg", torch.arange(n) % 2 == 0)
    gaussians.add_buffer("segment", torch.arange(n, dtype=torch.int32) - 1)
    return gaussians


def grid_points(spacing: float, offset: float) -> torch.Tensor:
    axis = torch.arange(5, dtype=torch.float32) * spacing
    return torch.cartesian_prod(axis, axis, axis) + offset


def test_activations_and_grads_finite_for_extreme_raw_values() -> None:
    g = random_set(4)
    with torch.no_grad():
        g.params["log_scales"].copy_(torch.tensor([[30.0] * 3, [-30.0] * 3, [0.0] * 3, [18.0] * 3]))
        g.params["quats"].copy_(
            torch.tensor([[0.0] * 4, [1e-30, 0.0, 0.0, 0.0], [0.0, 3.0, 0.0, 4.0], [2.0, 0, 0, 0]])
        )
        g.params["opacity_logits"].copy_(torch.tensor([100.0, -100.0, 0.0, 50.0]))
    scales, quats, opacities = g.scales, g.quats, g.opacities
    (scales.sum() + (quats * torch.rand(4, 4)).sum() + opacities.sum()).backward()
    grads = [p.grad for p in g.params.values() if p.grad is not None]
    assert len(grads) == 3
    for tensor in (scales, quats, opacities, *grads):
        assert torch.isfinite(tensor).all()
    assert scales[0, 0].item() == pytest.approx(math.exp(MAX_LOG_SCALE), rel=1e-6)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0])
    assert torch.equal(quats[0], identity) and torch.equal(quats[1], identity)
    assert torch.allclose(quats[2], torch.tensor([0.0, 0.6, 0.0, 0.8]))
    assert torch.equal(g.params["quats"].grad[:2], torch.zeros(2, 4))
    assert opacities[0].item() == 1.0 and opacities[1].item() >= 0.0
    q = torch.randn(50, 4, generator=torch.Generator().manual_seed(1))
    assert torch.allclose(normalize_quats(q), q / q.norm(dim=-1, keepdim=True), atol=1e-7)


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_init_scale_equals_grid_spacing(offset: float) -> None:
    xyz = grid_points(0.25, offset)
    rgb = torch.rand_like(xyz)
    g = GaussianSet.from_points(xyz, rgb)
    assert torch.allclose(g.scales, torch.full_like(xyz, 0.25), rtol=1e-3)
    assert torch.allclose(g.params["sh_dc"][:, 0] * SH_C0 + 0.5, rgb, atol=1e-6)
    assert torch.allclose(g.opacities, torch.full((len(g),), 0.1), atol=1e-6)
    assert torch.equal(g.quats, torch.tensor([1.0, 0, 0, 0]).expand(len(g), 4))
    assert g.params["sh_rest"].shape == (len(g), 15, 3) and not g.params["sh_rest"].any()


@pytest.mark.parametrize("unit", [1.0, 1e-3, 1e-6])
def test_initial_scales_follow_the_units_of_a_small_cloud(unit: float) -> None:
    # a 0.01 grid, and apart from it 4 points at one place (squared distance 0: the floor)
    xyz = torch.cat([grid_points(0.01, 0.0), torch.full((4, 3), 0.2)]) * unit
    g = GaussianSet.from_points(xyz, torch.rand_like(xyz))
    assert torch.allclose(g.scales[:-4], torch.full_like(xyz[:-4], 0.01 * unit), rtol=1e-3)
    # the 3DGS floor sqrt(1e-7) for a cloud of size >= 1, scaled by the size below it
    size = float((xyz.amax(dim=0) - xyz.amin(dim=0)).norm())
    floor = math.sqrt(1e-7) * min(size, 1.0)
    assert torch.allclose(g.scales[-4:], torch.full((4, 3), floor), rtol=1e-4)
    assert bool((g.scales[-4:] < 0.01 * unit).all())  # never larger than the cloud's spacing


def test_knn_matches_brute_force_across_blocks() -> None:
    gen = torch.Generator().manual_seed(3)
    clusters = torch.randn(8, 3, generator=gen) * 50
    pts = clusters[torch.randint(0, 8, (1500,), generator=gen)] + torch.rand(1500, 3, generator=gen)
    result = mean_sq_knn_distance(pts, k=3, chunk_elements=4096)
    dist = torch.cdist(pts.double(), pts.double()).square()
    dist.fill_diagonal_(float("inf"))
    expected = dist.topk(3, largest=False).values.mean(dim=1)
    assert torch.allclose(result.double(), expected, rtol=1e-3, atol=1e-7)


def test_init_degenerate_clouds() -> None:
    single = GaussianSet.from_points(torch.zeros(1, 3), torch.zeros(1, 3))
    assert torch.allclose(single.scales, torch.full((1, 3), math.sqrt(1e-7)))
    duplicates = GaussianSet.from_points(torch.ones(5, 3), torch.zeros(5, 3))
    assert torch.isfinite(duplicates.params["log_scales"]).all()
    with pytest.raises(InputError, match="xyz"):
        GaussianSet.from_points(torch.zeros(0, 3), torch.zeros(0, 3))
    with pytest.raises(InputError, match="rgb"):
        GaussianSet.from_points(torch.zeros(4, 3), torch.zeros(4, 4))


def test_sh_degree_schedule_and_colors() -> None:
    g = random_set(3)
    counts = {}
    for step in (0, 999, 1000, 2500, 3000, 9000):
        g.active_sh_degree = sh_degree_for_step(step, g.max_sh_degree)
        counts[step] = g.colors().shape[1]
    assert counts == {0: 1, 999: 1, 1000: 4, 2500: 9, 3000: 16, 9000: 16}
    assert sh_degree_for_step(500, 2, every=100) == 2
    with pytest.raises(InputError, match="sh_degree"):
        g.colors(4)


def test_tensor_round_trip_is_exact() -> None:
    g = with_extras(random_set(7))
    g.active_sh_degree = 2
    tensors = g.to_tensors(prefix="fg.")
    restored = GaussianSet.from_tensors({**tensors, "bg.means": torch.zeros(1, 3)}, prefix="fg.")
    again = restored.to_tensors(prefix="fg.")
    assert sorted(again) == sorted(tensors)
    for key, value in tensors.items():
        assert again[key].dtype == value.dtype and torch.equal(again[key], value), key
    assert restored.extra_param_names == ["gamma"] and restored.active_sh_degree == 2
    assert restored.params["gamma"].requires_grad
    with pytest.raises(InputError, match=r"fg\.bogus"):
        GaussianSet.from_tensors({**tensors, "fg.bogus": torch.zeros(7)}, prefix="fg.")


def test_subset_concat_clone_keep_rows_aligned_and_names_checked() -> None:
    g = with_extras(random_set(6))
    part = g.subset(torch.tensor([True, False, True, False, False, True]))
    assert torch.equal(part.params["gamma"], g.params["gamma"][[0, 2, 5]])
    assert torch.equal(part.buffers["segment"], torch.tensor([-1, 1, 4], dtype=torch.int32))
    joined = g.concat(part)
    assert len(joined) == 9
    assert torch.equal(joined.means[6:], g.means[[0, 2, 5]])
    assert torch.equal(joined.buffers["is_fg"][6:], g.buffers["is_fg"][[0, 2, 5]])
    copy = g.clone()
    with torch.no_grad():
        copy.params["means"].add_(1.0)
    assert not torch.equal(copy.means, g.means)
    with pytest.raises(InputError, match="differ"):
        g.concat(random_set(2))
    with pytest.raises(InputError, match="already registered"):
        g.add_buffer("means", torch.zeros(6))
    with pytest.raises(InputError, match="6 rows"):
        g.add_param("delta", torch.zeros(3, 3))
    with pytest.raises(InputError, match="floating point"):
        g.add_param("ids", torch.zeros(6, dtype=torch.int64))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float16, torch.bfloat16, torch.float64])
def test_inverse_sigmoid_is_finite_at_0_and_1_in_every_float_dtype(dtype):
    logits = inverse_sigmoid(torch.tensor([0.0, 0.5, 1.0], dtype=dtype))
    assert logits.dtype == dtype
    assert torch.isfinite(logits).all()
    assert logits[0] < 0 == logits[1] < logits[2]


def test_from_points_makes_every_tensor_on_the_points_device(monkeypatch):
    # the meta device stands in for a GPU (its nearest-neighbour search is data-dependent, so
    # the distances are faked): a CPU tensor among CUDA ones would fail the first step there
    monkeypatch.setattr(gaussians_module, "mean_sq_knn_distance", lambda xyz, k: xyz.new_ones(4))
    made = GaussianSet.from_points(torch.rand(4, 3, device="meta"), torch.rand(4, 3))
    devices = {name: t.device.type for name, t in made.to_tensors().items() if t.ndim}
    assert devices == dict.fromkeys(devices, "meta") and "sh_rest" in devices
