"""DeformationMLP and DeformationField: shapes, identity at init, head switches, fg/bg isolation."""

import pytest
import torch
from torch import nn

from relaygs.errors import InputError
from relaygs.field import DeformationField, DeformationMLP, Deltas, HeadSwitches

BOX = [[-2.0, -1.0, 0.0], [2.0, 1.0, 3.0]]
WIDTHS = {"dxyz": 3, "dscale": 3, "drot": 4, "dopacity": 1}


def small_field(isolate_fg_bg: bool, **kwargs) -> DeformationField:
    return DeformationField(
        BOX, 5, isolate_fg_bg=isolate_fg_bg, spatial_resolution=8, channels=4, width=16, **kwargs
    )


def randomise_heads(module: nn.Module) -> None:
    """Give the zero-initialised last layers random weights so every path carries gradient."""
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for name, parameter in module.named_parameters():
            if "heads" in name:
                parameter.copy_(torch.randn(parameter.shape, generator=generator) * 0.3)


def points(count: int = 40) -> tuple[torch.Tensor, int]:
    """Positions in BOX, the first two thirds background (the stages' row layout)."""
    generator = torch.Generator().manual_seed(0)
    xyz = torch.rand(count, 3, generator=generator) * torch.tensor([4.0, 2.0, 3.0])
    return xyz + torch.tensor([-2.0, -1.0, 0.0]), 2 * count // 3


@pytest.mark.parametrize("isolate", [False, True])
def test_shapes_and_identity_at_init(isolate: bool) -> None:
    field = small_field(isolate)
    xyz, num_background = points()
    deltas = field(xyz, 0.3, num_background)
    assert isinstance(deltas, Deltas)
    for name, width in WIDTHS.items():
        value = getattr(deltas, name)
        assert value.shape == (40, width)
        assert value.dtype == torch.float32
        assert torch.equal(value, torch.zeros_like(value))
    assert field(torch.zeros(0, 3), 0.5, 0).drot.shape == (0, 4)
    groups = field.parameter_groups()  # a partition: the grid's and the MLP sets' parameters
    assert set(groups) == {"grid", "mlp"}
    assert [id(p) for p in groups["grid"]] == [id(p) for p in field.hexplane.parameters()]
    assert {id(p) for p in groups["grid"] + groups["mlp"]} == {id(p) for p in field.parameters()}
    assert len(groups["grid"]) + len(groups["mlp"]) == len(list(field.parameters()))


@pytest.mark.parametrize("heads", [HeadSwitches(), HeadSwitches(dscale=False, dopacity=False)])
def test_the_single_node_mlp_equals_its_layers(heads: HeadSwitches) -> None:
    # the depth-0 MLP runs as one autograd node; its values and gradients are the layers'
    mlp = DeformationMLP(8, width=16, heads=heads).double()
    randomise_heads(mlp)
    features = torch.randn(50, 8, dtype=torch.float64)
    weights = {name: torch.randn(50, width, dtype=torch.float64) for name, width in WIDTHS.items()}
    results = []
    for by_layers in (False, True):
        mlp.zero_grad()
        x = features.clone().requires_grad_()
        if by_layers:
            shared = torch.relu(mlp.trunk(x))
            deltas = {name: head[1:](shared) for name, head in mlp.heads.items()}
        else:
            deltas = {name: getattr(mlp(x), name) for name in mlp.heads}
        sum((deltas[name] * weights[name]).sum() for name in deltas).backward()
        results.append([*deltas.values(), x.grad, *(p.grad for p in mlp.parameters())])
    for got, expected in zip(*results, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)
    x = features[:6].clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x: tuple(mlp(x))[:1], (x,))


@pytest.mark.parametrize("depth", [0, 1])
def test_bfloat16_products_keep_float32_values_and_gradients_near_float32(depth: int) -> None:
    # the products round to bfloat16 (8 bits of mantissa) and a ReLU near 0 may flip, so values
    # agree to 2 % of their largest and gradients to 15 % in norm (a wrong product or a lost
    # gradient is off by ~100 %); all of it stays float32
    results = []
    for matmul_dtype in ("float32", "bfloat16"):
        torch.manual_seed(3)
        mlp = DeformationMLP(8, width=32, depth=depth, matmul_dtype=matmul_dtype)
        randomise_heads(mlp)
        x = torch.randn(200, 8).requires_grad_()
        deltas = mlp(x)
        weights = torch.randn(200, 3)
        (deltas.dxyz * weights).sum().backward()
        grads = [p.grad for p in mlp.parameters() if p.grad is not None]
        results.append([*deltas, x.grad, *grads])
    for index, (exact, reduced) in enumerate(zip(*results, strict=True)):
        assert reduced.dtype == torch.float32 and torch.isfinite(reduced).all()
        if index < len(Deltas._fields):
            assert (reduced - exact).abs().max() <= 0.02 * exact.abs().max()
        else:
            assert (reduced - exact).norm() <= 0.15 * exact.norm()
    assert not torch.equal(results[0][0], results[1][0])  # the products did run in bfloat16
    with pytest.raises(InputError, match="matmul_dtype"):
        DeformationMLP(8, matmul_dtype="float16")


def test_mlp_layers_and_switched_off_heads() -> None:
    mlp = DeformationMLP(32)
    linears = [m for m in mlp.trunk if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(32, 128)]
    assert set(mlp.heads) == set(WIDTHS)
    deeper = DeformationMLP(32, width=64, depth=2)
    assert sum(isinstance(m, nn.Linear) for m in deeper.trunk) == 3
    for name, head in deeper.heads.items():
        assert head[-1].out_features == WIDTHS[name]
        assert torch.equal(head[-1].weight, torch.zeros_like(head[-1].weight))
    mlp = DeformationMLP(8, width=16, heads=HeadSwitches(dscale=False, dopacity=False))
    assert set(mlp.heads) == {"dxyz", "drot"}
    randomise_heads(mlp)
    deltas = mlp(torch.rand(10, 8))
    assert torch.equal(deltas.dscale, torch.zeros(10, 3))
    assert torch.equal(deltas.dopacity, torch.zeros(10, 1))
    assert deltas.dxyz.abs().sum().item() > 0.0
    assert deltas.drot.abs().sum().item() > 0.0


def test_gradients_reach_grid_and_mlp_but_not_across_groups() -> None:
    field = small_field(isolate_fg_bg=True)
    xyz, num_background = points()
    # At init only the zero last layers get gradient: the deform starts from identity.
    sum(d.sum() for d in field(xyz, 0.6, num_background)).backward()
    for mlp in field.mlp_sets.values():
        assert mlp.heads["dxyz"][-1].weight.grad.abs().sum().item() > 0.0
    field.zero_grad()
    randomise_heads(field)
    sum(d.square().sum() for d in field(xyz, torch.rand(40), num_background)).backward()
    for name, parameter in field.named_parameters():
        assert parameter.grad is not None, name
        assert parameter.grad.abs().sum().item() > 0.0, name
    # the background's deltas do not depend on the foreground MLPs
    deltas = field(xyz, 0.5, num_background)
    background_output = sum(d[:num_background].square().sum() for d in deltas)
    fg_params = list(field.mlp_sets["foreground"].parameters())
    bg_params = list(field.mlp_sets["background"].parameters())
    grads = torch.autograd.grad(
        background_output, fg_params + bg_params, allow_unused=True, materialize_grads=True
    )
    assert all(torch.equal(g, torch.zeros_like(g)) for g in grads[: len(fg_params)])
    assert sum(g.abs().sum().item() for g in grads[len(fg_params) :]) > 0.0


@pytest.mark.parametrize("isolate", [False, True])
def test_rows_go_through_the_mlp_set_of_their_group_without_device_reads(
    isolate: bool, monkeypatch
) -> None:
    field = small_field(isolate)
    names = ("background", "foreground") if isolate else ("all", "all")
    assert sorted(field.mlp_sets) == sorted(set(names))
    randomise_heads(field)
    xyz, num_background = points()
    with torch.no_grad():
        reads = []
        for name in ("__bool__", "__int__", "__index__", "item", "tolist"):
            original = getattr(torch.Tensor, name)

            def counted(self, *args, _original=original, **kwargs):
                reads.append(self.shape)
                return _original(self, *args, **kwargs)

            monkeypatch.setattr(torch.Tensor, name, counted)
        deltas = field(xyz, 0.8, num_background)
        monkeypatch.undo()
        assert reads == []
        halves = (slice(0, num_background), slice(num_background, None))
        for name, rows in zip(names, halves, strict=True):
            want = field.mlp_sets[name](field.hexplane(xyz[rows], 0.8))
            for got, expected in zip(deltas, want, strict=True):
                torch.testing.assert_close(got[rows], expected)
    for bad in (-1, len(xyz) + 1):
        with pytest.raises(InputError, match="num_background"):
            field(xyz, 0.3, bad)


def test_a_still_background_gets_zero_deltas_and_no_mlp_set() -> None:
    field = small_field(isolate_fg_bg=True, background_motion=False)
    assert sorted(field.mlp_sets) == ["foreground"]
    randomise_heads(field)
    moving = small_field(isolate_fg_bg=True)
    moving.load_state_dict(field.state_dict(), strict=False)  # same grid and foreground set
    xyz, num_background = points()
    deltas = field(xyz, 0.7, num_background)
    for got, want in zip(deltas, moving(xyz, 0.7, num_background), strict=True):
        assert torch.equal(got[:num_background], torch.zeros_like(got[:num_background]))
        torch.testing.assert_close(got[num_background:], want[num_background:])
    field.zero_grad()
    sum(d.square().sum() for d in field(xyz, torch.rand(40), num_background)).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in field.parameters())
    # one shared set moves every Gaussian: the setting has nothing to keep still
    assert small_field(isolate_fg_bg=False, background_motion=False).background_motion


def test_regularisers_come_from_the_grid() -> None:
    field = small_field(isolate_fg_bg=False)
    assert field.regularisers().keys() == field.hexplane.regularisers().keys()
    assert field.regularisers()["plane_smoothness"].item() > 0.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu() -> None:
    field = small_field(isolate_fg_bg=True)
    randomise_heads(field)
    xyz, num_background = points()
    with torch.no_grad():
        expected = field(xyz, 0.4, num_background)
        got = field.cuda()(xyz.cuda(), 0.4, num_background)
    for g, e in zip(got, expected, strict=True):
        torch.testing.assert_close(g.cpu(), e, rtol=1e-4, atol=1e-5)
