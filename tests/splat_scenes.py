"""Scene builders shared by the splatting tests."""

from __future__ import annotations

import math

import torch

from relaygs.data import Camera
from relaygs.data.synthetic.rig import dome_rig


def camera_rig(
    num_cameras: int, width: int, height: int, focal: float | None = None, dtype=torch.float32
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cameras near the origin looking down +z, slightly offset from each other."""
    focal = float(width) if focal is None else focal
    viewmats = torch.eye(4, dtype=dtype).repeat(num_cameras, 1, 1)
    viewmats[:, 0, 3] = torch.linspace(-0.3, 0.3, num_cameras, dtype=dtype)
    viewmats[:, 1, 3] = torch.linspace(0.1, -0.1, num_cameras, dtype=dtype)
    if num_cameras > 1:  # a small rotation about y for the later cameras
        angle = torch.linspace(0.0, 0.2, num_cameras, dtype=dtype)
        viewmats[:, 0, 0] = torch.cos(angle)
        viewmats[:, 0, 2] = torch.sin(angle)
        viewmats[:, 2, 0] = -torch.sin(angle)
        viewmats[:, 2, 2] = torch.cos(angle)
    K = torch.tensor([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1]], dtype=dtype)
    return viewmats, K.repeat(num_cameras, 1, 1)


def random_scene(
    n: int,
    *,
    seed: int = 0,
    num_cameras: int = 1,
    width: int = 40,
    height: int = 32,
    channels: int = 3,
    dtype=torch.float32,
    scale_range: tuple[float, float] = (0.02, 0.12),
) -> dict:
    """Random Gaussians in front of the rig; returns rasterization keyword arguments."""
    gen = torch.Generator().manual_seed(seed)
    means = torch.empty(n, 3, dtype=dtype)
    means[:, :2] = (torch.rand(n, 2, generator=gen, dtype=dtype) * 2 - 1) * 0.8
    means[:, 2] = torch.rand(n, generator=gen, dtype=dtype) * 2 + 2
    lo, hi = scale_range
    viewmats, Ks = camera_rig(num_cameras, width, height, dtype=dtype)
    return {
        "means": means,
        "quats": torch.randn(n, 4, generator=gen, dtype=dtype),
        "scales": torch.rand(n, 3, generator=gen, dtype=dtype) * (hi - lo) + lo,
        "opacities": torch.rand(n, generator=gen, dtype=dtype) * 0.9 + 0.05,
        "colors": torch.rand(n, channels, generator=gen, dtype=dtype),
        "viewmats": viewmats,
        "Ks": Ks,
        "width": width,
        "height": height,
    }


LEARNABLE = ("means", "quats", "scales", "opacities", "colors")


def on_device(scene: dict, device: str) -> dict:
    """Copy of a scene with every tensor on `device` (leaves, gradients not kept)."""
    return {k: v.detach().to(device) if torch.is_tensor(v) else v for k, v in scene.items()}


def with_grad(scene: dict, extra: tuple[str, ...] = ()) -> dict:
    """Copy of a scene whose learnable tensors (and `extra` keys) require grad."""
    out = dict(scene)
    for key in (*LEARNABLE, *extra):
        if key in out and out[key] is not None:
            out[key] = out[key].detach().clone().requires_grad_(True)
    return out


def render_and_grads(render_fn, scene: dict, seed: int = 0, **kwargs):
    """Render, backprop a fixed random projection of both outputs; return outputs and grads."""
    keys = [k for k in (*LEARNABLE, "backgrounds") if torch.is_tensor(scene.get(k))]
    colors, alphas, meta = render_fn(**scene, **kwargs)
    gen = torch.Generator().manual_seed(seed)
    # drawn on the CPU, so a render on another device is weighed by the same numbers
    w_c = torch.randn(colors.shape, generator=gen, dtype=colors.dtype).to(colors.device)
    w_a = torch.randn(alphas.shape, generator=gen, dtype=alphas.dtype).to(alphas.device)
    loss = (colors * w_c).sum() + (alphas * w_a).sum()
    grads = torch.autograd.grad(loss, [scene[k] for k in keys], allow_unused=True)
    return colors, alphas, meta, dict(zip(keys, grads, strict=True))


def assert_render_matches(got, expected, forward_atol: float, grad_rtol: float) -> None:
    """Colours and alphas within `forward_atol`; each gradient within `grad_rtol` relative
    (norm) of the expected one, or equal where that one is zero or absent."""
    torch.testing.assert_close(got[0], expected[0], rtol=0, atol=forward_atol)
    torch.testing.assert_close(got[1], expected[1], rtol=0, atol=forward_atol)
    assert_grads_match(got, expected, grad_rtol)


def assert_grads_match(got, expected, grad_rtol: float) -> None:
    """Each gradient within `grad_rtol` relative (norm) of the expected one, or equal where
    that one is zero or absent."""
    for key, grad in expected[3].items():
        mine = got[3][key]
        if grad is None or mine is None:  # unused (colours in depth mode): no gradient or zero
            assert all(g is None or torch.all(g == 0) for g in (grad, mine)), key
            continue
        assert torch.isfinite(mine).all(), key
        norm = grad.norm()
        if norm == 0:
            assert torch.all(mine == 0), key
        else:
            rel = (mine - grad).norm() / norm
            assert rel < grad_rtol, f"{key}: relative error {rel.item():.3g}"


HARD_WIDTH, HARD_HEIGHT = 24, 20


def hard_scene(hard: dict, dtype=torch.float32) -> dict:
    """Two ordinary Gaussians plus one hard Gaussian (row 2) described by `hard`."""
    viewmats, Ks = camera_rig(1, HARD_WIDTH, HARD_HEIGHT, dtype=dtype)
    viewmats = torch.eye(4, dtype=dtype)[None]
    scene = {
        "means": torch.tensor([[0.0, 0.0, 3.0], [0.2, -0.1, 2.5], [0.1, 0.1, 3.0]], dtype=dtype),
        "quats": torch.tensor([[1.0, 0, 0, 0], [0.9, 0.1, 0.2, 0.3], [1.0, 0, 0, 0]], dtype=dtype),
        "scales": torch.full((3, 3), 0.15, dtype=dtype),
        "opacities": torch.tensor([0.7, 0.5, 0.6], dtype=dtype),
        "colors": torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]], dtype=dtype),
        "viewmats": viewmats,
        "Ks": Ks,
        "width": HARD_WIDTH,
        "height": HARD_HEIGHT,
    }
    for key, value in hard.items():
        scene[key] = scene[key].clone()
        scene[key][2] = torch.as_tensor(value, dtype=dtype)
    return scene


# Hard cases for the Gaussian in row 2 of `hard_scene`: culled ones, and visible ones.
CULLED = {
    "at camera centre (z = 0)": {"means": [0.0, 0.0, 0.0]},
    "behind the camera": {"means": [0.1, 0.1, -2.0]},
    "just in front of the near plane's far side": {"means": [0.0, 0.0, 0.00999]},
    "far outside the frustum": {"means": [1e6, 0.0, 3.0]},
    "far outside, huge": {"means": [1e30, -1e30, 1e30]},
    "opacity exactly 0": {"opacities": 0.0},
    "log-scale 18": {"scales": [math.exp(18)] * 3},
    "log-scale 24": {"scales": [math.exp(24)] * 3},
    "log-scale 30": {"scales": [math.exp(30)] * 3},
    "scale 1e20": {"scales": [1e20] * 3},
    "scale 1e30, one axis": {"scales": [1e30, 1.0, 1.0]},
    "scale 3e38": {"scales": [3e38] * 3},
}


KEPT = {
    "exactly on the near plane": {"means": [0.0, 0.0, 0.01]},
    "zero quaternion": {"quats": [0.0, 0.0, 0.0, 0.0], "scales": [0.3, 0.1, 0.05]},
    "tiny quaternion": {"quats": [1e-30, 2e-30, 0.0, -1e-30], "scales": [0.3, 0.1, 0.05]},
    "huge quaternion": {"quats": [1e30, 2e30, 0.0, -1e30], "scales": [0.3, 0.1, 0.05]},
    "zero scale": {"scales": [0.0, 0.0, 0.0]},
    "scale 1e-8": {"scales": [1e-8, 1e-8, 1e-8]},
    "opacity exactly 1": {"opacities": 1.0},
    "screen-filling splat": {"scales": [50.0, 50.0, 50.0]},
    "flat disc": {"scales": [0.3, 0.3, 0.0]},
}


def dome_cameras(width: int, height: int) -> list[Camera]:
    """The synthetic scenes' dome rig as Cameras of the given image size."""
    return [
        Camera(
            index,
            torch.tensor(rig.K, dtype=torch.float32),
            torch.tensor(rig.w2c, dtype=torch.float32),
            width,
            height,
        )
        for index, rig in enumerate(dome_rig(width, height))
    ]


def projection_inputs(scene: dict) -> tuple:
    """A scene's arguments of `project_gaussians` (factors from its quats and scales)."""
    from relaygs.splat.projection import covariance_factor

    factors = covariance_factor(scene["quats"], scene["scales"])
    keys = ("opacities", "viewmats", "Ks", "width", "height")
    return (scene["means"], factors, *(scene[k] for k in keys))


def assert_projection_matches_torch(project, dtype) -> None:
    """`project` against the torch projection on a scene where some centres leave the frustum
    (clamped Jacobian), fall behind the near plane or outside the image: the same boxes and
    visibility, values and gradients to rounding."""
    from relaygs.splat.projection import project_gaussians

    scene = random_scene(600, seed=2, num_cameras=3, dtype=dtype, scale_range=(0.01, 0.6))
    scene["means"] = scene["means"] * torch.tensor([3.0, 3.0, 1.5], dtype=dtype) - 0.6
    results = []
    for run in (project_gaussians, project):
        weights = torch.Generator().manual_seed(7)
        inputs = with_grad({k: scene[k] for k in ("means", "quats", "scales")})
        proj = run(*projection_inputs({**scene, **inputs}))
        loss = sum(
            (getattr(proj, name) * torch.randn(getattr(proj, name).shape, generator=weights,
                                               dtype=dtype)).sum()
            for name in ("means2d", "conics", "depths")
        )  # fmt: skip
        loss.backward()
        results.append((proj, {k: v.grad for k, v in inputs.items()}))
    (expected, expected_grads), (got, grads) = results
    visible = expected.visible
    assert 0 < int(visible.sum()) < visible.numel()  # some pairs culled, most not
    for name in ("radii", "visible", "bounds"):  # same boxes (no value here sits on an edge)
        assert torch.equal(getattr(got, name), getattr(expected, name)), name
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for name in ("depths", "means2d", "conics"):  # rounding differs (summation order)
        value = getattr(expected, name)
        scale = float(value.detach().abs().max())
        torch.testing.assert_close(getattr(got, name), value, rtol=tol, atol=tol * scale)
    for key, grad in expected_grads.items():
        rel = (grads[key] - grad).norm() / grad.norm()
        assert rel < tol * 10, key
