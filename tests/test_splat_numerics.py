"""Hard cases of the splatting core: finite values and gradients, zero gradient when culled."""

from __future__ import annotations

import math
import re

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from relaygs.errors import InputError
from relaygs.splat import rasterization
from relaygs.splat.projection import ALPHA_MIN, MAX_SIGMA_MULT, opacity_sigma_multiplier
from relaygs.splat.reference import rasterization_reference
from splat_scenes import (
    CULLED,
    HARD_HEIGHT,
    HARD_WIDTH,
    KEPT,
    LEARNABLE,
    camera_rig,
    hard_scene,
    render_and_grads,
    with_grad,
)

# Every test here runs on both backends (the `splat_backend` fixture in conftest).
pytestmark = pytest.mark.usefixtures("splat_backend")

W, H = HARD_WIDTH, HARD_HEIGHT


def _assert_all_finite(colors, alphas, grads):
    assert torch.isfinite(colors).all() and torch.isfinite(alphas).all()
    for key, grad in grads.items():
        assert grad is not None and torch.isfinite(grad).all(), f"non-finite gradient of {key}"


@pytest.mark.parametrize("mode", ["classic", "antialiased"])
@pytest.mark.parametrize("hard", CULLED.values(), ids=CULLED.keys())
def test_culled_gaussian_is_finite_and_gets_exactly_zero_gradient(hard, mode):
    scene = with_grad(hard_scene(hard))
    colors, alphas, meta, grads = render_and_grads(rasterization, scene, rasterize_mode=mode)
    _assert_all_finite(colors, alphas, grads)
    assert meta["radii"][0, 2].tolist() == [0, 0]
    for key in LEARNABLE:
        assert torch.all(grads[key][2] == 0), f"culled Gaussian got a gradient on {key}"
        assert grads[key][:2].abs().sum() > 0, f"visible Gaussians lost their {key} gradient"


@pytest.mark.parametrize("render_mode", ["RGB", "RGB+D"])
@pytest.mark.parametrize("hard", CULLED.values(), ids=CULLED.keys())
def test_culled_gaussian_with_sh_colours_and_depth_is_finite_with_zero_gradient(hard, render_mode):
    """The SH view direction of a mean at the camera centre has no length: it must not reach
    the colours or the gradients as NaN, nor must the depth channel's division."""
    scene = hard_scene(hard)
    scene["colors"] = 0.3 * torch.randn(3, 16, 3, generator=torch.Generator().manual_seed(0))
    scene = with_grad(scene)
    colors, alphas, _, grads = render_and_grads(
        rasterization, scene, sh_degree=3, render_mode=render_mode
    )
    _assert_all_finite(colors, alphas, grads)
    for key in LEARNABLE:
        assert torch.all(grads[key][2] == 0), f"culled Gaussian got a gradient on {key}"


@pytest.mark.parametrize("render_mode", ["RGB", "D", "RGB+D"])
def test_nothing_in_view_renders_the_background_with_zero_gradient(render_mode):
    scene = hard_scene({})
    scene["means"] = scene["means"] * torch.tensor([1.0, 1.0, -1.0])  # all behind the camera
    scene = with_grad(scene)
    background = torch.tensor([[0.2, 0.4, 0.6]])
    colors, alphas, _, grads = render_and_grads(
        rasterization, scene, render_mode=render_mode, backgrounds=background
    )
    assert torch.all(alphas == 0)
    expected = {"RGB": [0.2, 0.4, 0.6], "D": [0.0], "RGB+D": [0.2, 0.4, 0.6, 0.0]}[render_mode]
    assert torch.equal(colors[0, 0, 0], torch.tensor(expected))
    for key, grad in grads.items():
        assert grad is None or torch.all(grad == 0), f"gradient on {key} with nothing in view"


@pytest.mark.parametrize("mode", ["classic", "antialiased"])
@pytest.mark.parametrize("hard", KEPT.values(), ids=KEPT.keys())
def test_hard_but_visible_gaussian_is_finite_and_matches_reference(hard, mode):
    """Also in the antialiased mode, whose opacity factor vanishes for a zero-area Gaussian."""
    scene = with_grad(hard_scene(hard, dtype=torch.float64))
    colors, alphas, meta, grads = render_and_grads(rasterization, scene, rasterize_mode=mode)
    ref_colors, ref_alphas, _, ref_grads = render_and_grads(
        rasterization_reference, scene, rasterize_mode=mode
    )
    _assert_all_finite(colors, alphas, grads)
    assert meta["radii"][0, 2].min() > 0
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-9)
    torch.testing.assert_close(alphas, ref_alphas, rtol=0, atol=1e-9)
    for key in LEARNABLE:
        scale = max(1.0, ref_grads[key].abs().max().item())
        torch.testing.assert_close(grads[key], ref_grads[key], rtol=1e-6, atol=1e-9 * scale)


def _needle(length: float, degrees: float, dtype) -> dict:
    """One needle Gaussian (scales [length, 1e-3, 1e-3]) turned `degrees` about the view axis,
    3 units in front of a 64×64 camera of focal 500: its image is long, thin and diagonal."""
    half = math.radians(degrees) / 2
    return {
        "means": torch.tensor([[0.0, 0.0, 3.0]], dtype=dtype),
        "quats": torch.tensor([[math.cos(half), 0.0, 0.0, math.sin(half)]], dtype=dtype),
        "scales": torch.tensor([[length, 1e-3, 1e-3]], dtype=dtype),
        "opacities": torch.tensor([0.8], dtype=dtype),
        "colors": torch.tensor([[1.0, 0.5, 0.2]], dtype=dtype),
        "viewmats": torch.eye(4, dtype=dtype)[None],
        "Ks": torch.tensor([[[500.0, 0, 32], [0, 500.0, 32], [0, 0, 1]]], dtype=dtype),
        "width": 64,
        "height": 64,
    }


def _needle_image_and_thin_gradient(length: float, degrees: float, dtype):
    """The needle's image, whether it was drawn, and the gradient of a fixed weighting of the
    image (the same numbers in either dtype) on its thin scale, all in float64."""
    scene = with_grad(_needle(length, degrees, dtype))
    colors, _, meta = rasterization(**scene)
    weights = torch.randn(colors.shape, generator=torch.Generator().manual_seed(0), dtype=float)
    (grad,) = torch.autograd.grad((colors * weights.to(dtype)).sum(), [scene["scales"]])
    return colors.detach().double(), bool(meta["visible"].all()), grad[0, 1].double()


@pytest.mark.parametrize(("length", "degrees"), [(3.0, 45.0), (10.0, 30.0), (30.0, 30.0)])
def test_a_long_thin_gaussian_at_an_angle_renders_in_float32_as_in_float64(length, degrees):
    """a·c − b² cancels in float32 for such a Gaussian (σ 500–5000 px by 0.17 px): it was
    misshaped (0.007–0.04 off, gradients 2–7 % off) or culled."""
    image, drawn, grad = _needle_image_and_thin_gradient(length, degrees, torch.float32)
    exact_image, _, exact_grad = _needle_image_and_thin_gradient(length, degrees, torch.float64)
    assert drawn
    torch.testing.assert_close(image, exact_image, rtol=0, atol=1e-3)
    torch.testing.assert_close(grad, exact_grad, rtol=2e-3, atol=0)


@pytest.mark.parametrize("scales", [[1e-8] * 3, [0.5, 1e-12, 1e-12]], ids=["speck", "needle"])
def test_without_the_2d_blur_a_vanishing_gaussian_keeps_finite_gradients(scales):
    """With eps2d = 0 the 2D determinant of a tiny Gaussian underflows in the backward's
    det²: such a Gaussian is culled (zero gradient) rather than given NaN."""
    scene = with_grad(hard_scene({"scales": scales}))
    scene["Ks"] = torch.tensor([[[20.0, 0, W / 2], [0, 20.0, H / 2], [0, 0, 1]]])
    colors, alphas, _, grads = render_and_grads(rasterization, scene, eps2d=0.0)
    _assert_all_finite(colors, alphas, grads)


@pytest.mark.parametrize(
    ("means", "near_plane"),
    [
        ([1e35, 0.0, 3.0], 0.01),
        ([0.0, -1e35, 3.0], 0.01),
        ([1e-3, 0.0, 1e-9], 1e-9),
        ([3e37, 0.0, 0.05], 0.01),
        ([0.0, 3e37, 0.05], 0.01),
        ([1e31, 0.0, 1e-8], 1e-9),
    ],
    ids=[
        "far to the side",
        "far below",
        "nearly on the camera",
        "x/z overflows",
        "y/z overflows",
        "x/z overflows near the camera",
    ],
)
def test_extreme_positions_under_a_long_lens_are_culled_with_zero_gradient(means, near_plane):
    """fx·x/z (or x/z itself) overflows for such a centre: it is culled, its offsets zeroed
    before the division."""
    scene = with_grad(hard_scene({"means": means}))
    scene["Ks"] = torch.tensor([[[1e5, 0, W / 2], [0, 1e5, H / 2], [0, 0, 1]]])
    colors, alphas, meta, grads = render_and_grads(rasterization, scene, near_plane=near_plane)
    _assert_all_finite(colors, alphas, grads)
    assert not bool(meta["visible"][0, 2])
    assert grads["means"][2].abs().sum() == 0


@pytest.mark.parametrize("quat", [[1e-30, 2e-30, 0.0, -1e-30], [1e30, 2e30, 0.0, -1e30]])
def test_quaternion_norm_does_not_change_the_image(quat):
    q = torch.tensor(quat, dtype=torch.float64)
    odd = hard_scene({"quats": quat, "scales": [0.3, 0.1, 0.05]}, dtype=torch.float64)
    unit = hard_scene(
        {
            "quats": (q / q.abs().max() / torch.linalg.norm(q / q.abs().max())).tolist(),
            "scales": [0.3, 0.1, 0.05],
        },
        dtype=torch.float64,
    )
    torch.testing.assert_close(
        rasterization(**odd)[0], rasterization(**unit)[0], rtol=0, atol=1e-12
    )


@pytest.mark.parametrize("quat", [[0.0] * 4, [1e-39, -2e-39, 0.0, 0.0]])  # zero, denormal
def test_vanishing_quaternion_renders_as_identity_with_zero_gradient(quat):
    zero = with_grad(hard_scene({"quats": quat, "scales": [0.3, 0.1, 0.05]}))
    ident = hard_scene({"quats": [1.0, 0, 0, 0], "scales": [0.3, 0.1, 0.05]})
    colors, _, _, grads = render_and_grads(rasterization, zero)
    torch.testing.assert_close(colors, rasterization(**ident)[0], rtol=0, atol=1e-6)
    assert torch.all(grads["quats"][2] == 0)


def test_thousands_of_stacked_opaque_gaussians():
    n = 2000
    viewmats = torch.eye(4)[None]
    _, Ks = camera_rig(1, W, H)
    gen = torch.Generator().manual_seed(0)
    scene = with_grad(
        {
            "means": torch.tensor([0.0, 0.0, 3.0]) + torch.randn(n, 3, generator=gen) * 1e-3,
            "quats": torch.randn(n, 4, generator=gen),
            "scales": torch.tensor([0.03, 0.015, 0.01]).repeat(n, 1),
            "opacities": torch.full((n,), 0.999),
            "colors": torch.rand(n, 3, generator=gen),
            "viewmats": viewmats,
            "Ks": Ks,
            "width": W,
            "height": H,
        }
    )
    colors, alphas, _, grads = render_and_grads(rasterization, scene)
    _assert_all_finite(colors, alphas, grads)
    centre = alphas[0, H // 2, W // 2, 0]
    assert centre > 1 - 2e-4, "the stack saturates the centre pixel (early stop at T < 1e-4)"
    ref_colors, ref_alphas, _, ref_grads = render_and_grads(rasterization_reference, scene)
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-5)
    torch.testing.assert_close(alphas, ref_alphas, rtol=0, atol=1e-5)
    for key in LEARNABLE:
        rel = (grads[key] - ref_grads[key]).norm() / ref_grads[key].norm()
        assert rel < 1e-4, f"{key}: relative error {rel.item():.3g}"
    # Past the early stop the Gaussians behind get exactly no gradient.
    assert (grads["colors"].abs().sum(-1) == 0).sum() > n // 2


def test_large_motion_across_the_frustum_stays_finite():
    """A Gaussian swept from far left, through the view, to behind the camera."""
    for x in [*torch.linspace(-1e4, 1e4, 9).tolist(), 0.0]:
        for z in (-5.0, 0.0, 0.005, 0.5, 3.0, 1e6):
            scene = with_grad(hard_scene({"means": [x, 0.3 * x, z], "scales": [2.0, 0.01, 0.5]}))
            colors, alphas, _, grads = render_and_grads(rasterization, scene)
            _assert_all_finite(colors, alphas, grads)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(1, 12),
    seed=st.integers(0, 2**31 - 1),
    log_scale=st.floats(-20.0, 32.0),
    spread=st.floats(1e-3, 1e6),
    depth=st.floats(-1e3, 1e6),
    quat_mag=st.floats(-30.0, 30.0),
    focal=st.floats(1e-2, 1e5),
    opacity=st.floats(0.0, 1.0),
)
def test_no_nan_for_wide_random_inputs(n, seed, log_scale, spread, depth, quat_mag, focal, opacity):
    gen = torch.Generator().manual_seed(seed)
    _, Ks = camera_rig(2, 16, 12, focal=focal)
    scene = with_grad(
        {
            "means": torch.randn(n, 3, generator=gen) * spread + torch.tensor([0.0, 0.0, depth]),
            "quats": torch.randn(n, 4, generator=gen) * 10.0**quat_mag,
            "scales": torch.exp(torch.randn(n, 3, generator=gen) + log_scale),
            "opacities": torch.rand(n, generator=gen) * opacity,
            "colors": torch.rand(n, 3, generator=gen),
            "viewmats": camera_rig(2, 16, 12)[0],
            "Ks": Ks,
            "width": 16,
            "height": 12,
            "backgrounds": torch.rand(2, 3, generator=gen),
        },
        extra=("backgrounds",),
    )
    colors, alphas, _, grads = render_and_grads(rasterization, scene)
    _assert_all_finite(colors, alphas, grads)
    assert alphas.min() >= 0 and alphas.max() <= 1


def test_bitwise_deterministic_on_cpu():
    from splat_scenes import random_scene

    scene = with_grad(random_scene(400, seed=3, num_cameras=2, width=48, height=40))
    first = render_and_grads(rasterization, scene)
    second = render_and_grads(rasterization, scene)
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
    for key in LEARNABLE:
        assert torch.equal(first[3][key], second[3][key]), key


def test_gradcheck_float64_tiny_scene():
    dt = torch.float64
    gen = torch.Generator().manual_seed(0)
    means = torch.tensor(
        [[0.0, 0, 3], [0.2, 0.1, 2.5], [-0.3, 0.2, 3.5], [0.1, -0.3, 2.8]], dtype=dt
    )
    inputs = (
        means,
        torch.randn(4, 4, generator=gen, dtype=dt),
        torch.rand(4, 3, generator=gen, dtype=dt) * 0.2 + 0.1,
        torch.rand(4, generator=gen, dtype=dt) * 0.5 + 0.3,
        torch.rand(4, 3, generator=gen, dtype=dt),
        torch.rand(2, 3, generator=gen, dtype=dt),
    )
    viewmats, _ = camera_rig(2, 8, 8, dtype=dt)
    Ks = torch.tensor([[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]], dtype=dt).repeat(2, 1, 1)

    def render(m, q, s, o, c, bg):
        return rasterization(m, q, s, o, c, viewmats, Ks, 8, 8, backgrounds=bg)[:2]

    args = tuple(t.clone().requires_grad_(True) for t in inputs)
    assert torch.autograd.gradcheck(render, args, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_gradcheck_float64_sh_and_depth():
    dt = torch.float64
    gen = torch.Generator().manual_seed(1)
    inputs = (
        torch.tensor([[0.0, 0, 3], [0.2, 0.1, 2.5], [-0.2, 0.1, 2.9]], dtype=dt),
        torch.randn(3, 4, generator=gen, dtype=dt),
        torch.rand(3, 3, generator=gen, dtype=dt) * 0.2 + 0.1,
        torch.rand(3, generator=gen, dtype=dt) * 0.5 + 0.3,
        torch.randn(3, 16, 3, generator=gen, dtype=dt) * 0.3,
    )
    Ks = torch.tensor([[[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]]], dtype=dt)

    def render(m, q, s, o, sh):
        out = rasterization(
            m, q, s, o, sh, torch.eye(4, dtype=dt)[None], Ks, 8, 8, sh_degree=3, render_mode="RGB+D"
        )
        return out[:2]

    args = tuple(t.clone().requires_grad_(True) for t in inputs)
    assert torch.autograd.gradcheck(render, args, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_means2d_carries_the_screen_space_gradient():
    from splat_scenes import random_scene

    scene = with_grad(random_scene(50, seed=2))
    colors, _, meta = rasterization(**scene)
    colors.sum().backward()
    grad = meta["means2d"].grad
    assert grad is not None and grad.shape == (1, 50, 2)
    visible = meta["radii"][0].amax(-1) > 0
    assert grad[0][visible].abs().sum() > 0 and torch.all(grad[0][~visible] == 0)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"means": torch.zeros(3, 2)}, "means must be [N,3]"),
        ({"quats": torch.zeros(2, 4)}, "quats must be [3,4]"),
        ({"opacities": torch.zeros(3, 1)}, "opacities must be [3]"),
        ({"Ks": torch.zeros(2, 3, 3)}, "Ks must be [1,3,3]"),
        ({"width": 0}, "width and height must be positive"),
        ({"render_mode": "RGBD"}, "render_mode must be one of"),
        ({"sh_degree": 4, "colors": torch.zeros(3, 25, 3)}, "sh_degree must be 0..3"),
        ({"backgrounds": torch.zeros(1, 4)}, "backgrounds must be [1,3]"),
        ({"Ks": torch.tensor([[[0.0, 0, 12], [0, 24.0, 10], [0, 0, 1]]])}, "fx, fy in (0, 1e+20]"),
        ({"Ks": torch.tensor([[[24.0, 0, 12], [0, -24.0, 10], [0, 0, 1]]])}, "fx, fy in (0, 1e+"),
        # fx/depth² in the projection's backward would overflow: NaN gradients, not an image
        ({"Ks": torch.tensor([[[1e36, 0, 12], [0, 24.0, 10], [0, 0, 1]]])}, "fx, fy in (0, 1e+"),
        ({"tile_size": 0}, "tile_size must be an int >= 1, got 0"),
        ({"tile_size": -1}, "tile_size must be an int >= 1, got -1"),
        ({"colors": torch.zeros(3, 0)}, "colors must be [N,D] or [C,N,D] with N=3, C=1, D>=1"),
        ({"Ks": torch.tensor([[[24.0, 0, 12], [0, 24.0, math.inf], [0, 0, 1]]])}, "finite"),
        # a depth of 0 inside [near, far] would divide by zero in the projection
        ({"near_plane": 0.0}, "1e-09 <= near_plane < far_plane"),
        ({"near_plane": 1e-30}, "1e-09 <= near_plane < far_plane, got 1e-30 and"),
        ({"near_plane": float("nan")}, "1e-09 <= near_plane < far_plane"),
        ({"near_plane": 2.0, "far_plane": 1.0}, "1e-09 <= near_plane < far_plane"),
        ({"eps2d": -0.3}, "eps2d must be finite and >= 0"),
        ({"eps2d": float("inf")}, "eps2d must be finite and >= 0"),
    ],
)
def test_bad_inputs_raise_one_line_errors(change, message):
    scene = {**hard_scene({}), **change}
    with pytest.raises(InputError, match=re.escape(message)):
        rasterization(**scene)


def test_sigma_multiplier_is_zero_below_the_alpha_threshold():
    opacities = torch.tensor([0.0, 1e-30, 0.5 * ALPHA_MIN, ALPHA_MIN, 0.01, 1.0])
    mult = opacity_sigma_multiplier(opacities)
    assert torch.isfinite(mult).all()
    assert mult[:4].tolist() == [0.0] * 4
    # alpha = o·exp(−m²/2) falls to 1/255 at m = sqrt(2·ln(255·o)), at most MAX_SIGMA_MULT
    for opacity, value in zip(opacities[4:].tolist(), mult[4:].tolist(), strict=True):
        expected = math.sqrt(2 * math.log(opacity / ALPHA_MIN))
        assert value == pytest.approx(expected, rel=1e-5) and value <= MAX_SIGMA_MULT
