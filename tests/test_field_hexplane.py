"""HexPlane: feature shapes, time/space coordinate mapping, gradients and regularisers, on
both paths (`splat_backend`: torch's grid_sample, or the native kernel on CPU)."""

import pytest
import torch
from torch.func import functional_call

from relaygs.errors import InputError
from relaygs.field import HexPlane
from relaygs.field.hexplane import second_difference_energy

UNIT_BOX = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]

pytestmark = pytest.mark.usefixtures("splat_backend")


def tiny_hexplane(resolution: int = 4, time_resolution: int = 5) -> HexPlane:
    """One level, one channel, spatial planes 1 and time planes 1: features are exactly 1."""
    hexplane = HexPlane(
        UNIT_BOX, time_resolution, multires=[1], spatial_resolution=resolution, channels=1
    )
    with torch.no_grad():
        hexplane.spatial_planes[0].fill_(1.0)
    return hexplane


def test_feature_shape_and_initial_ranges() -> None:
    hexplane = HexPlane(UNIT_BOX, 8, multires=[1, 2], spatial_resolution=16, channels=16)
    features = hexplane(torch.rand(50, 3) * 2 - 1, 0.4)
    assert hexplane.feature_dim == 32
    assert features.shape == (50, 32)
    assert features.dtype == torch.float32
    assert [p.shape[-1] for p in hexplane.spatial_planes] == [16, 32]
    assert [p.shape[-2] for p in hexplane.time_planes] == [8, 8]
    for plane in hexplane.spatial_planes:
        assert plane.min().item() >= 0.1 and plane.max().item() <= 0.5
    for plane in hexplane.time_planes:
        assert torch.equal(plane, torch.ones_like(plane))
    # Time planes 1 at init: each channel is a product of three values in [0.1, 0.5].
    assert features.min().item() >= 0.1**3 - 1e-6
    assert features.max().item() <= 0.5**3 + 1e-6


@pytest.mark.parametrize(("t", "expected"), [(0.0, 10.0), (0.25, 20.0), (0.5, 30.0), (1.0, 50.0)])
def test_time_spans_full_grid(t: float, expected: float) -> None:
    hexplane = tiny_hexplane(time_resolution=5)
    rows = torch.tensor([10.0, 20.0, 30.0, 40.0, 50.0])
    with torch.no_grad():
        hexplane.time_planes[0][0, 0] = rows[:, None].expand(5, 4)  # xt plane, rows = time
    features = hexplane(torch.rand(7, 3) * 2 - 1, t)
    torch.testing.assert_close(features, torch.full((7, 1), expected))


def test_per_point_times() -> None:
    hexplane = tiny_hexplane(time_resolution=3)
    with torch.no_grad():
        hexplane.time_planes[0][1, 0] = torch.tensor([[2.0], [3.0], [4.0]]).expand(3, 4)  # yt
    features = hexplane(torch.zeros(3, 3), torch.tensor([0.0, 0.5, 1.0]))
    torch.testing.assert_close(features[:, 0], torch.tensor([2.0, 3.0, 4.0]))


def test_bounding_box_maps_to_grid_corners() -> None:
    box = [[2.0, -4.0, 0.0], [6.0, 0.0, 1.0]]
    hexplane = HexPlane(box, 2, multires=[1], spatial_resolution=4, channels=1)
    with torch.no_grad():
        hexplane.spatial_planes[0].fill_(1.0)
        hexplane.spatial_planes[0][0, 0] = torch.arange(4.0)[None, :].expand(4, 4) + 1  # xy: x
    # min corner, max corner, centre, and two points outside the box (border padding).
    points = torch.tensor(
        [[2.0, -2.0, 0.5], [6.0, -2.0, 0.5], [4.0, -2.0, 0.5], [9.0, -2.0, 0.5], [0.0, 5.0, 7.0]]
    )
    features = hexplane(points, 0.0)
    torch.testing.assert_close(features[:, 0], torch.tensor([1.0, 4.0, 2.5, 4.0, 1.0]))


def test_zero_extent_axis_stays_finite() -> None:
    hexplane = HexPlane([[0.0, 0.0, 1.0], [1.0, 1.0, 1.0]], 4, spatial_resolution=8)
    xyz = torch.tensor([[0.5, 0.5, 1.0], [0.2, 0.7, 3.0]], requires_grad=True)
    hexplane(xyz, 0.5).sum().backward()
    assert torch.isfinite(hexplane.half_extent).all()
    assert torch.isfinite(xyz.grad).all()
    for plane in [*hexplane.spatial_planes, *hexplane.time_planes]:
        assert torch.isfinite(plane.grad).all()


def test_points_and_times_outside_the_grid_have_finite_gradients() -> None:
    hexplane = HexPlane(UNIT_BOX, 4, multires=[1, 2], spatial_resolution=8, channels=2)
    xyz = torch.tensor([[5.0, -7.0, 0.0], [1e6, 1e6, -1e6], [0.3, 0.2, 0.1]], requires_grad=True)
    times = torch.tensor([-0.5, 2.0, 1.0])
    hexplane(xyz, times).square().sum().backward()
    assert torch.isfinite(xyz.grad).all()
    for plane in [*hexplane.spatial_planes, *hexplane.time_planes]:
        assert torch.isfinite(plane.grad).all() and float(plane.grad.abs().sum()) > 0.0


def test_gradcheck_float64() -> None:
    hexplane = HexPlane(UNIT_BOX, 3, multires=[1], spatial_resolution=3, channels=2).double()
    generator = torch.Generator().manual_seed(0)
    spatial = torch.rand(3, 2, 3, 3, dtype=torch.float64, generator=generator)
    time = torch.rand(3, 2, 3, 3, dtype=torch.float64, generator=generator) + 0.5
    xyz = torch.rand(4, 3, dtype=torch.float64, generator=generator) * 1.6 - 0.8
    t = torch.rand(4, dtype=torch.float64, generator=generator) * 0.8 + 0.1
    inputs = tuple(x.requires_grad_() for x in (spatial, time, xyz, t))

    def sample(spatial: torch.Tensor, time: torch.Tensor, xyz: torch.Tensor, t: torch.Tensor):
        params = {"spatial_planes.0": spatial, "time_planes.0": time}
        return functional_call(hexplane, params, (xyz, t))

    assert torch.autograd.gradcheck(sample, inputs)
    # a frame time without gradient (as the stages give it) takes the native kernel there
    assert torch.autograd.gradcheck(lambda *a: sample(*a, t.detach()), inputs[:3])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("channels", [4, 16])  # 16: the kernel's compiled-in channel count
def test_both_paths_give_the_same_features_and_gradients(dtype: torch.dtype, channels: int) -> None:
    hexplane = HexPlane(
        [[-1.0, -2.0, -1.0], [1.0, 2.0, 3.0]],
        5,
        multires=[1, 2],
        spatial_resolution=8,
        channels=channels,
    ).to(dtype)
    generator = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for plane in hexplane.time_planes:
            plane.copy_(torch.rand(plane.shape, generator=generator, dtype=dtype) + 0.5)
    # points inside, outside (border-clamped) and on the box's faces
    xyz = torch.rand(300, 3, generator=generator, dtype=dtype) * 3.0 - 1.5
    xyz[:20, 0] = 1.0
    xyz = xyz * torch.tensor([1.0, 2.0, 2.0], dtype=dtype) + torch.tensor(
        [0.0, 0.0, 1.0], dtype=dtype
    )
    weights = torch.randn(300, hexplane.feature_dim, generator=generator, dtype=dtype)
    results = []
    for features_of in (hexplane, lambda x, t: hexplane._sampled(hexplane.normalise(x), t * 2 - 1)):
        hexplane.zero_grad()
        points = xyz.clone().requires_grad_()
        features = features_of(points, torch.full((300,), 0.37, dtype=dtype))
        (features * weights).sum().backward()
        results.append([features, points.grad, *(p.grad for p in hexplane.parameters())])
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    for got, expected in zip(*results, strict=True):
        scale = float(expected.detach().abs().max())
        torch.testing.assert_close(got, expected, rtol=tol, atol=tol * scale)


def test_regularisers_vanish_on_flat_planes() -> None:
    hexplane = HexPlane(UNIT_BOX, 6, multires=[1, 2], spatial_resolution=5, channels=2)
    with torch.no_grad():
        hexplane.spatial_planes[0].fill_(0.3)
        hexplane.spatial_planes[1].fill_(0.2)
    terms = hexplane.regularisers()
    assert set(terms) == {"plane_smoothness", "time_smoothness", "time_l1"}
    for value in terms.values():
        assert value.item() == 0.0
    # A linear ramp has no second difference (first-difference TV would not vanish).
    with torch.no_grad():
        ramp = torch.linspace(0.0, 1.0, 6)[:, None].expand(6, 5)
        hexplane.time_planes[0].copy_(ramp.expand_as(hexplane.time_planes[0]))
    assert hexplane.time_smoothness().item() == pytest.approx(0.0, abs=1e-12)
    assert hexplane.time_l1().item() > 0.0


def test_regularisers_positive_on_random_planes_with_gradients_to_them() -> None:
    hexplane = HexPlane(UNIT_BOX, 6, multires=[1, 2], spatial_resolution=5, channels=2)
    with torch.no_grad():
        for plane in hexplane.time_planes:
            plane.uniform_(0.0, 2.0)
    terms = hexplane.regularisers()
    assert all(value.item() > 0.0 for value in terms.values())
    sum(terms.values()).backward()
    for plane in [*hexplane.spatial_planes, *hexplane.time_planes]:
        assert float(plane.grad.abs().sum()) > 0.0


@pytest.mark.parametrize("dims", [(2,), (3,), (2, 3)])
def test_second_difference_gradient_passes_gradcheck(dims: tuple[int, ...]) -> None:
    # The closed-form backward against finite differences, on planes of unequal sides.
    planes = torch.rand(2, 3, 5, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p: second_difference_energy(p, dims), (planes,))


def test_second_difference_of_short_planes_is_zero_without_gradient_flow() -> None:
    planes = torch.rand(3, 2, 2, 6, requires_grad=True)
    energy = second_difference_energy(planes, (2,))
    assert energy.item() == 0.0 and not energy.requires_grad


def test_bad_inputs_raise_one_line_errors() -> None:
    hexplane = tiny_hexplane()
    with pytest.raises(InputError, match=r"xyz: expected shape \[N, 3\]"):
        hexplane(torch.zeros(4, 2), 0.0)
    with pytest.raises(InputError, match=r"t: expected a scalar or shape \[4\]"):
        hexplane(torch.zeros(4, 3), torch.zeros(3))
    with pytest.raises(InputError, match="aabb"):
        HexPlane([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]], 4)
    with pytest.raises(InputError, match="time_resolution"):
        HexPlane(UNIT_BOX, 0)
    with pytest.raises(InputError, match="multires"):
        HexPlane(UNIT_BOX, 4, multires=[])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu() -> None:
    hexplane = HexPlane(UNIT_BOX, 6, spatial_resolution=8, channels=4)
    xyz = torch.rand(100, 3) * 2 - 1
    expected = hexplane(xyz, 0.7)
    got = hexplane.cuda()(xyz.cuda(), 0.7)
    torch.testing.assert_close(got.cpu(), expected)


def test_time_l1_is_the_mean_absolute_distance_from_one_per_plane_summed() -> None:
    # xt at -2 is 3 away, yt at 2 is 1 away, zt (still 1) 0 away: 3 + 1 + 0 = 4 (without the
    # absolute value yt would count as -1)
    hexplane = tiny_hexplane(resolution=3, time_resolution=4)
    with torch.no_grad():
        hexplane.time_planes[0][0].fill_(-2.0)
        hexplane.time_planes[0][1].fill_(2.0)
    assert hexplane.time_l1().item() == pytest.approx(4.0)
    # two levels of two channels: level 0's xt has one channel at 3 (2 away) and one at 1, mean
    # 1; level 1's zt is all 0.5 (0.5 away): 1.5
    hexplane = HexPlane(UNIT_BOX, 3, multires=[1, 2], spatial_resolution=2, channels=2)
    with torch.no_grad():
        hexplane.time_planes[0][0, 0].fill_(3.0)
        hexplane.time_planes[1][2].fill_(0.5)
    assert hexplane.time_l1().item() == pytest.approx(1.5)
