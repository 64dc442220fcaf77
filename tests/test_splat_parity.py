"""The fast splatting path matches the dense reference renderer, forward and backward."""

from __future__ import annotations

import math

import pytest
import torch

from relaygs.splat import rasterization
from relaygs.splat.reference import rasterization_reference
from splat_scenes import on_device, random_scene, render_and_grads, with_grad

# Every test here runs on both backends (the `splat_backend` fixture in conftest).
pytestmark = pytest.mark.usefixtures("splat_backend")

CASES = [
    # (seed, n, cameras, width, height, channels, background)
    (0, 60, 1, 40, 32, 3, False),
    (1, 150, 4, 40, 32, 3, True),
    (2, 120, 1, 37, 29, 32, True),
    (3, 200, 4, 24, 40, 32, False),
    (4, 300, 1, 64, 48, 3, True),
]


def _scene(seed, n, cams, width, height, channels, background, dtype):
    scene = random_scene(
        n, seed=seed, num_cameras=cams, width=width, height=height, channels=channels, dtype=dtype
    )
    if background:
        gen = torch.Generator().manual_seed(seed + 100)
        scene["backgrounds"] = torch.rand(cams, channels, generator=gen, dtype=dtype)
    return scene


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"seed{c[0]}-n{c[1]}-C{c[2]}-D{c[5]}")
def test_forward_matches_reference_float32(case):
    scene = _scene(*case, dtype=torch.float32)
    colors, alphas, meta = rasterization(**scene)
    ref_colors, ref_alphas, _ = rasterization_reference(**scene)
    assert meta["num_pairs"] > 0
    assert (ref_alphas > 0.1).any(), "scene should cover part of the image"
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-5)
    torch.testing.assert_close(alphas, ref_alphas, rtol=0, atol=1e-5)


def _assert_grads_close(fast: dict, ref: dict) -> None:
    for key, expected in ref.items():
        got = fast[key]
        if got is None and expected is None:  # input unused in this render mode
            continue
        assert got is not None and expected is not None, key
        assert expected.abs().max() > 0, f"{key}: reference gradient is identically zero"
        err = (got - expected).abs()
        allowed = torch.clamp(1e-4 * expected.abs(), min=1e-6)
        worst = (err - allowed).max()
        assert worst <= 0, f"{key}: max excess {worst.item():.3g} over rel 1e-4 / abs 1e-6"


def _assert_grads_close_float32(fast: dict, ref: dict) -> None:
    for key, expected in ref.items():
        rel = (fast[key] - expected).norm() / expected.norm()
        assert rel < 1e-4, f"{key}: relative error {rel.item():.3g}"


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"seed{c[0]}-n{c[1]}-C{c[2]}-D{c[5]}")
def test_gradients_match_reference_float64(case):
    scene = _scene(*case, dtype=torch.float64)
    scene = with_grad(scene, extra=("backgrounds",))
    _, _, _, fast = render_and_grads(rasterization, scene)
    _, _, _, ref = render_and_grads(rasterization_reference, scene)
    _assert_grads_close(fast, ref)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("case", CASES, ids=lambda c: f"seed{c[0]}-n{c[1]}-C{c[2]}-D{c[5]}")
def test_cuda_matches_cpu_forward_and_backward(case, dtype):
    scene = _scene(*case, dtype=dtype)
    extra = ("backgrounds",)
    cpu = render_and_grads(rasterization, with_grad(scene, extra))
    gpu = render_and_grads(rasterization, with_grad(on_device(scene, "cuda"), extra))
    atol = 1e-5 if dtype == torch.float32 else 1e-10
    for got, expected in zip(gpu[:2], cpu[:2], strict=True):
        torch.testing.assert_close(got.cpu(), expected, rtol=0, atol=atol)
    torch.testing.assert_close(gpu[2]["radii"].cpu(), cpu[2]["radii"])
    on_cpu = {k: g.cpu() for k, g in gpu[3].items()}
    if dtype == torch.float64:
        _assert_grads_close(on_cpu, cpu[3])
    else:
        _assert_grads_close_float32(on_cpu, cpu[3])


@pytest.mark.parametrize("eps2d", [0.1, 0.3])
def test_antialiased_mode_matches_reference(eps2d):
    """The opacity factor's gradient reaches the conics and through them the projection."""
    scene = with_grad(_scene(9, 150, 2, 40, 32, 3, True, torch.float64), extra=("backgrounds",))
    options = {"rasterize_mode": "antialiased", "eps2d": eps2d}
    colors, _, _, fast = render_and_grads(rasterization, scene, **options)
    ref_colors, _, _, ref = render_and_grads(rasterization_reference, scene, **options)
    classic, _, _, _ = render_and_grads(rasterization, scene, eps2d=eps2d)
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-9)
    assert (colors - classic).abs().max() > 1e-3, "the opacity factor should change the image"
    _assert_grads_close(fast, ref)


def test_gradients_match_reference_float32():
    scene = with_grad(_scene(5, 200, 2, 40, 32, 3, True, torch.float32), extra=("backgrounds",))
    _, _, _, fast = render_and_grads(rasterization, scene)
    _, _, _, ref = render_and_grads(rasterization_reference, scene)
    _assert_grads_close_float32(fast, ref)


@pytest.mark.parametrize("mode", ["D", "RGB+D"])
def test_depth_modes_match_reference(mode):
    scene = with_grad(_scene(6, 100, 2, 32, 24, 3, True, torch.float64), extra=("backgrounds",))
    colors, _, _, fast = render_and_grads(rasterization, scene, render_mode=mode)
    ref_colors, _, _, ref = render_and_grads(rasterization_reference, scene, render_mode=mode)
    assert colors.shape[-1] == (1 if mode == "D" else 4)
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-9)
    depth = colors[..., -1]
    assert depth.max() > 2.0 and depth.max() < 4.5, "expected depth lies in the scene's z range"
    _assert_grads_close(fast, ref)


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_spherical_harmonics_match_reference(degree):
    scene = _scene(7, 80, 4, 32, 24, 3, False, torch.float64)
    gen = torch.Generator().manual_seed(7)
    scene["colors"] = torch.randn(80, 16, 3, generator=gen, dtype=torch.float64) * 0.3
    scene = with_grad(scene)
    colors, _, _, fast = render_and_grads(rasterization, scene, sh_degree=degree)
    ref_colors, _, _, ref = render_and_grads(rasterization_reference, scene, sh_degree=degree)
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-9)
    _assert_grads_close(fast, ref)
    if degree < 3:  # unused higher-order coefficients get no gradient
        assert fast["colors"][:, (degree + 1) ** 2 :].abs().max() == 0


@pytest.mark.parametrize("tile_size", [4, 8, 16])
def test_tile_size_does_not_change_the_image(tile_size):
    scene = _scene(8, 150, 2, 45, 33, 3, True, torch.float32)
    colors, alphas, _ = rasterization(**scene, tile_size=tile_size)
    ref_colors, ref_alphas, _ = rasterization_reference(**scene)
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-5)
    torch.testing.assert_close(alphas, ref_alphas, rtol=0, atol=1e-5)


def test_single_gaussian_matches_closed_form():
    """An isotropic Gaussian straight ahead: pixel values follow o·exp(−d²/2σ²) with the blur."""
    f, z, s, o = 20.0, 2.0, 0.05, 0.8
    scene = {
        "means": torch.tensor([[0.0, 0.0, z]]),
        "quats": torch.tensor([[1.0, 0, 0, 0]]),
        "scales": torch.full((1, 3), s),
        "opacities": torch.tensor([o]),
        "colors": torch.ones(1, 1),
        "viewmats": torch.eye(4)[None],
        "Ks": torch.tensor([[[f, 0, 8.0], [0, f, 8.0], [0, 0, 1]]]),
        "width": 16,
        "height": 16,
    }
    colors, _, meta = rasterization(**scene)
    var = float((f * s / z) ** 2 + 0.3)
    ys, xs = torch.meshgrid(torch.arange(16) + 0.5, torch.arange(16) + 0.5, indexing="ij")
    expected = o * torch.exp(-((xs - 8) ** 2 + (ys - 8) ** 2) / (2 * var))
    expected = torch.where(expected >= 1 / 255, expected, torch.zeros_like(expected))
    torch.testing.assert_close(colors[0, ..., 0], expected, rtol=0, atol=1e-6)
    radius = math.ceil(math.sqrt(2 * math.log(255 * o) * var))  # opacity-aware extent
    assert meta["radii"][0, 0].tolist() == [radius, radius]
