"""The splatting core against closed-form values computed here, independently of its code.

The dense reference renderer shares projection, SH evaluation, camera centres and depth
finishing with the fast path, so the parity tests cannot see a bug in those. These tests
build every expected value in numpy (float64) from first principles: rotations from
Rodrigues' formula, the EWA covariance J·W·R·S·Sᵀ·Rᵀ·Wᵀ·Jᵀ + 0.3·I, the 3DGS alpha rule
α = min(0.99, o·exp(−½ dᵀΣ⁻¹d)) kept when α ≥ 1/255, and the real SH basis of degree 1.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from relaygs.splat import rasterization

# Constants of the 3DGS / gsplat rasteriser, written out as literals on purpose.
EPS2D = 0.3  # px² blur added to the 2D covariance diagonal
ALPHA_CLAMP = 0.99
ALPHA_SKIP = 1.0 / 255.0
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199

W, H = 48, 40
FX, FY, CX, CY = 52.0, 47.0, 23.0, 21.5


def _rodrigues(axis, angle: float) -> np.ndarray:
    """Rotation by `angle` about `axis`: I + sinθ·K + (1 − cosθ)·K²."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def _quat_wxyz(axis, angle: float, norm: float = 1.0) -> np.ndarray:
    """wxyz quaternion of the same rotation, scaled to `norm` (the API accepts any norm)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return norm * np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """The textbook unit-quaternion (w, x, y, z) rotation matrix."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _camera(rot: np.ndarray, trans) -> tuple[torch.Tensor, torch.Tensor]:
    """viewmats [1,4,4] (world→camera [R|t]) and Ks [1,3,3] for the module's intrinsics."""
    view = np.eye(4)
    view[:3, :3] = rot
    view[:3, 3] = trans
    K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
    return torch.from_numpy(view)[None], torch.from_numpy(K)[None]


def _world_point(rot: np.ndarray, trans, pixel, depth: float) -> np.ndarray:
    """The world point seen at sub-pixel position `pixel` (x, y) at camera depth `depth`."""
    p_cam = np.array([(pixel[0] - CX) * depth / FX, (pixel[1] - CY) * depth / FY, depth])
    return rot.T @ (p_cam - np.asarray(trans))


def _screen_gaussian(
    mean, rot_g, scales, rot_cam, trans, blur: float = EPS2D
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic EWA projection: 2D mean (px) and 2D covariance (px²), `blur` included."""
    x, y, z = rot_cam @ mean + np.asarray(trans)
    m = rot_g @ np.diag(scales)
    cov_cam = rot_cam @ m @ m.T @ rot_cam.T
    jac = np.array([[FX / z, 0.0, -FX * x / z**2], [0.0, FY / z, -FY * y / z**2]])
    cov2d = jac @ cov_cam @ jac.T + blur * np.eye(2)
    return np.array([FX * x / z + CX, FY * y / z + CY]), cov2d


def _raw_alpha(mean2d, cov2d, opacity) -> np.ndarray:
    """o·exp(−½ dᵀΣ⁻¹d) at every pixel centre (j + 0.5, i + 0.5), [H,W], no box, no clamp."""
    ys, xs = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    d = np.stack([xs - mean2d[0], ys - mean2d[1]], axis=-1)
    inv = np.linalg.inv(cov2d)
    power = 0.5 * np.einsum("...i,ij,...j->...", d, inv, d)
    return opacity * np.exp(-power)


def _alpha(raw: np.ndarray) -> np.ndarray:
    """The 3DGS rule: clamp at 0.99, drop below 1/255."""
    return np.where(raw >= ALPHA_SKIP, np.minimum(raw, ALPHA_CLAMP), 0.0)


def _away_from_skip(raw: np.ndarray) -> np.ndarray:
    """Pixels whose raw alpha is not within rounding of the 1/255 skip threshold."""
    return np.abs(raw - ALPHA_SKIP) > 1e-9


def _render(means, quats, scales, opacities, colors, viewmats, Ks, **kwargs):
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    return rasterization(
        t(means), t(quats), t(scales), t(opacities), t(colors), viewmats, Ks, W, H, **kwargs
    )


# A rotated, translated camera (R is not symmetric, t is not zero), shared by several tests.
CAM_ROT = _rodrigues([0.3, -0.5, 0.8], 0.55)
CAM_T = np.array([0.4, -0.3, 1.2])


def test_quaternion_formula_used_here_agrees_with_rodrigues():
    """Sanity check of this module's own helpers, so later expectations rest on two derivations."""
    axis, angle = [0.2, 0.9, -0.4], 1.1
    np.testing.assert_allclose(
        _quat_to_matrix(_quat_wxyz(axis, angle, 3.0)), _rodrigues(axis, angle), atol=1e-14
    )


def test_rotated_anisotropic_gaussian_matches_the_ewa_covariance():
    """Rotated, elongated, off-centre Gaussian seen by a rotated camera: meta and image."""
    axis, angle = [0.6, -0.3, 0.75], 0.9  # w, x, y, z all well away from zero
    scales = np.array([0.45, 0.08, 0.2])
    mean = _world_point(CAM_ROT, CAM_T, (11.3, 28.7), 3.2)  # left of and below the centre
    mean2d, cov2d = _screen_gaussian(mean, _rodrigues(axis, angle), scales, CAM_ROT, CAM_T)
    viewmats, Ks = _camera(CAM_ROT, CAM_T)

    colors, alphas, meta = _render(
        [mean], [_quat_wxyz(axis, angle, 2.5)], [scales], [0.8], [[0.2, 0.5, 0.9]], viewmats, Ks
    )

    inv = np.linalg.inv(cov2d)
    expected_conic = [inv[0, 0], inv[0, 1], inv[1, 1]]
    np.testing.assert_allclose(meta["means2d"][0, 0].numpy(), mean2d, rtol=0, atol=1e-9)
    np.testing.assert_allclose(meta["conics"][0, 0].numpy(), expected_conic, rtol=1e-9)
    assert abs(cov2d[0, 1]) > 0.2 * math.sqrt(cov2d[0, 0] * cov2d[1, 1]), "should be tilted"

    raw = _raw_alpha(mean2d, cov2d, 0.8)
    expected = _alpha(raw)
    ok = _away_from_skip(raw)
    assert (expected > 0).sum() > 40, "the splat should cover many pixels"
    np.testing.assert_allclose(alphas[0, ..., 0].numpy()[ok], expected[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        colors[0].numpy()[ok], expected[ok][:, None] * [0.2, 0.5, 0.9], rtol=0, atol=1e-9
    )


def test_off_centre_gaussian_jacobian_sign():
    """Isotropic Gaussians far left and far right of the principal point (identity camera).

    Their screen ellipses lean along the line of sight; a sign error in the −fx·x/z² term of
    the Jacobian changes the covariance only off the centre, so one Gaussian on each side.
    """
    rot, trans = np.eye(3), np.zeros(3)
    viewmats, Ks = _camera(rot, trans)
    means = [_world_point(rot, trans, (7.5, 9.5), 1.5), _world_point(rot, trans, (40.5, 31.5), 1.5)]
    scales = np.full(3, 0.08)
    _, alphas, meta = _render(
        means, [[1.0, 0, 0, 0]] * 2, [scales] * 2, [0.9, 0.9], [[1.0]] * 2, viewmats, Ks
    )
    expected = np.zeros((H, W))
    ok = np.ones((H, W), dtype=bool)
    for row, mean in enumerate(means):
        mean2d, cov2d = _screen_gaussian(mean, np.eye(3), scales, rot, trans)
        inv = np.linalg.inv(cov2d)
        np.testing.assert_allclose(
            meta["conics"][0, row].numpy(), [inv[0, 0], inv[0, 1], inv[1, 1]], rtol=1e-9
        )
        raw = _raw_alpha(mean2d, cov2d, 0.9)
        expected += _alpha(raw)  # the two splats do not overlap
        ok &= _away_from_skip(raw)
    np.testing.assert_allclose(alphas[0, ..., 0].numpy()[ok], expected[ok], rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_pixel_with_alpha_above_the_skip_is_rendered(seed):
    """Many small splats at random sub-pixel positions and opacities, compared densely.

    The expected image evaluates every Gaussian at every pixel (no box), so a pixel box
    that misses a column or row where α ≥ 1/255 shows up as a missing pixel.
    """
    rng = np.random.default_rng(seed)
    rot, trans = np.eye(3), np.zeros(3)
    viewmats, Ks = _camera(rot, trans)
    depth, cells = 2.0, 12  # 4 × 3 cells of 12 px, one splat per cell, no overlap
    means, opacities, scales = [], [], []
    for gy in range(H // cells):
        for gx in range(W // cells):
            pixel = (
                gx * cells + 6 + rng.uniform(-0.5, 0.5),
                gy * cells + 6 + rng.uniform(-0.5, 0.5),
            )
            means.append(_world_point(rot, trans, pixel, depth))
            opacities.append(rng.uniform(0.05, 1.0))
            scales.append(rng.uniform(0.01, 0.045, size=3))
    quats = [_quat_wxyz(rng.normal(size=3), rng.uniform(0, math.pi)) for _ in means]
    _, alphas, _ = _render(means, quats, scales, opacities, np.ones((len(means), 1)), viewmats, Ks)
    expected = np.zeros((H, W))
    ok = np.ones((H, W), dtype=bool)
    for mean, quat, scale, opacity in zip(means, quats, scales, opacities, strict=True):
        mean2d, cov2d = _screen_gaussian(mean, _quat_to_matrix(quat), scale, rot, trans)
        assert 3 * math.sqrt(max(cov2d[0, 0], cov2d[1, 1])) < 5.5, "splats must not overlap"
        raw = _raw_alpha(mean2d, cov2d, opacity)
        expected += _alpha(raw)
        ok &= _away_from_skip(raw)
    got = alphas[0, ..., 0].numpy()
    missing = ok & (expected > 0) & (got == 0)
    assert not missing.any(), f"pixels with alpha >= 1/255 not rendered: {np.argwhere(missing)}"
    np.testing.assert_allclose(got[ok], expected[ok], rtol=0, atol=1e-9)


def test_antialiased_mode_keeps_a_small_gaussians_screen_integral():
    """Mip-Splatting's 2D filter: the blurred covariance B = Σ + 0.3·I as in classic mode, the
    opacity scaled by √(det Σ / det B), so o·2π√det Σ, the splat's screen integral without the
    blur, is kept: a Gaussian of a few tenths of a pixel no longer renders as a bright pixel."""
    axis, angle = [0.2, 0.7, -0.4], 0.6
    scales = np.array([0.012, 0.004, 0.008])  # under half a pixel on screen
    mean = _world_point(CAM_ROT, CAM_T, (24.3, 19.6), 2.0)
    rot_g = _rodrigues(axis, angle)
    mean2d, blurred = _screen_gaussian(mean, rot_g, scales, CAM_ROT, CAM_T)
    _, sharp = _screen_gaussian(mean, rot_g, scales, CAM_ROT, CAM_T, blur=0.0)
    factor = math.sqrt(np.linalg.det(sharp) / np.linalg.det(blurred))
    assert 0.05 < factor < 0.9, "the blur should dominate the splat"
    viewmats, Ks = _camera(CAM_ROT, CAM_T)

    _, alphas, _ = _render(
        [mean], [_quat_wxyz(axis, angle)], [scales], [0.9], [[1.0]], viewmats, Ks,
        rasterize_mode="antialiased",
    )  # fmt: skip

    raw = _raw_alpha(mean2d, blurred, 0.9 * factor)
    ok = _away_from_skip(raw)
    assert (_alpha(raw) > 0).sum() >= 4
    np.testing.assert_allclose(alphas[0, ..., 0].numpy()[ok], _alpha(raw)[ok], rtol=0, atol=1e-9)
    integral = 0.9 * 2 * math.pi * math.sqrt(np.linalg.det(sharp))
    assert alphas.sum().item() == pytest.approx(integral, rel=0.05)  # pixels skipped: < 5 %


def test_opaque_gaussian_alpha_is_clamped_at_0_99():
    """Opacity 1 on a pixel centre: that pixel's alpha is exactly the 3DGS clamp 0.99."""
    viewmats, Ks = _camera(CAM_ROT, CAM_T)
    mean = _world_point(CAM_ROT, CAM_T, (20.5, 17.5), 2.5)
    colors, alphas, _ = _render(
        [mean], [[1.0, 0, 0, 0]], [[0.2, 0.2, 0.2]], [1.0], [[0.5, 1.0, 0.25]], viewmats, Ks
    )
    assert alphas[0, 17, 20, 0].item() == pytest.approx(0.99, abs=1e-12)
    np.testing.assert_allclose(colors[0, 17, 20].numpy(), [0.495, 0.99, 0.2475], atol=1e-12)
    assert alphas.max().item() == pytest.approx(0.99, abs=1e-12)


@pytest.mark.parametrize("render_mode", ["D", "RGB+D"])
def test_expected_depth_of_a_translucent_gaussian_is_its_camera_depth(render_mode):
    """Opacity 0.3: every pixel it reaches reports its camera-space z, others report 0."""
    depth = 2.75
    viewmats, Ks = _camera(CAM_ROT, CAM_T)
    mean = _world_point(CAM_ROT, CAM_T, (30.5, 12.5), depth)
    assert (CAM_ROT @ mean + CAM_T)[2] == pytest.approx(depth)
    scales = [0.15, 0.1, 0.12]
    colors, alphas, _ = _render(
        [mean], [[1.0, 0, 0, 0]], [scales], [0.3], [[0.1, 0.2, 0.3]], viewmats, Ks,
        render_mode=render_mode,
    )  # fmt: skip
    got = colors[0, ..., -1].numpy()
    assert got[12, 30] == pytest.approx(depth, rel=1e-12)
    mean2d, cov2d = _screen_gaussian(mean, np.eye(3), np.array(scales), CAM_ROT, CAM_T)
    raw = _raw_alpha(mean2d, cov2d, 0.3)
    ok = _away_from_skip(raw)
    expected = np.where(raw >= ALPHA_SKIP, depth, 0.0)
    assert (expected > 0).sum() > 20
    np.testing.assert_allclose(got[ok], expected[ok], rtol=1e-12, atol=0)
    np.testing.assert_allclose(alphas[0, ..., 0].numpy()[ok], _alpha(raw)[ok], atol=1e-9)


def _sh1_color(dc, c1, c2, c3, direction) -> np.ndarray:
    """Degree-1 real SH colour, 3DGS convention: C0·dc − C1·y·c1 + C1·z·c2 − C1·x·c3 + 0.5."""
    x, y, z = direction
    rgb = SH_C0 * dc - SH_C1 * y * c1 + SH_C1 * z * c2 - SH_C1 * x * c3 + 0.5
    return np.maximum(rgb, 0.0)


def test_sh_degree_1_colour_follows_the_view_direction_from_the_camera_centre():
    """Colour of a degree-1 SH Gaussian seen from a rotated and translated camera.

    The camera centre is −Rᵀt and the view direction is normalize(mean − centre); both are
    computed here, and the rendered colour at the centre pixel is 0.99 times the SH colour.
    """
    viewmats, Ks = _camera(CAM_ROT, CAM_T)
    mean = _world_point(CAM_ROT, CAM_T, (15.5, 24.5), 3.0)
    centre = -CAM_ROT.T @ CAM_T
    direction = (mean - centre) / np.linalg.norm(mean - centre)
    # Per channel (r, g, b): one DC and three degree-1 coefficients, all non-zero.
    dc = np.array([0.4, -0.2, 0.1])
    c1 = np.array([0.5, -0.3, 0.2])
    c2 = np.array([-0.25, 0.45, 0.3])
    c3 = np.array([0.35, 0.15, -0.5])
    coeffs = np.stack([dc, c1, c2, c3])[None]  # [1, 4, 3]
    expected = _sh1_color(dc, c1, c2, c3, direction)
    assert (expected > 0.05).all(), "keep every channel away from the clamp at 0"

    colors, alphas, meta = _render(
        [mean], [[1.0, 0, 0, 0]], [[0.1, 0.1, 0.1]], [1.0], coeffs, viewmats, Ks, sh_degree=1
    )
    np.testing.assert_allclose(meta["features"][0, 0].numpy(), expected, rtol=1e-12)
    assert alphas[0, 24, 15, 0].item() == pytest.approx(0.99, abs=1e-12)
    np.testing.assert_allclose(colors[0, 24, 15].numpy(), 0.99 * expected, rtol=1e-12)
    covered = alphas[0, ..., 0].numpy() > 0
    np.testing.assert_allclose(
        colors[0].numpy()[covered],
        alphas[0].numpy()[covered] * expected[None],
        rtol=1e-12,
    )
