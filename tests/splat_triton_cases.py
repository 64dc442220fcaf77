"""The Triton compositing kernels on CPU tensors in Triton's interpreter: forward and
gradients against the dense reference and the torch backend on tiny random scenes, the hard
cases of test_splat_numerics.py, early stop, fixed layers and odd tile sizes.

Not collected by the suite itself: test_splat_triton.py runs this file in a child pytest with
TRITON_INTERPRET=1, which must be set before triton is first imported and would otherwise
stay in force for every later test of the process.
"""

from __future__ import annotations

import os

import pytest
import torch

from relaygs.errors import InputError
from relaygs.splat import FixedLayer, rasterization
from relaygs.splat.reference import rasterization_reference
from splat_scenes import (
    CULLED,
    HARD_HEIGHT,
    HARD_WIDTH,
    KEPT,
    LEARNABLE,
    assert_projection_matches_torch,
    assert_render_matches,
    camera_rig,
    hard_scene,
    projection_inputs,
    random_scene,
    render_and_grads,
    with_grad,
)

if os.environ.get("TRITON_INTERPRET") != "1":
    pytest.skip("run by test_splat_triton.py with TRITON_INTERPRET=1", allow_module_level=True)
pytest.importorskip("triton", reason="triton is not installed (the dev extra brings it)")


def test_the_kernels_run_in_the_interpreter():
    from relaygs.splat import triton as gpu

    assert gpu.available() and gpu.interpreted()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
def test_the_projection_kernels_match_the_torch_projection(dtype):
    from relaygs.splat.triton.projection import project_gaussians_triton

    assert_projection_matches_torch(project_gaussians_triton, dtype)


def test_the_projection_gradients_match_finite_differences():
    from relaygs.splat.fused_projection import FusedProjectGaussians
    from relaygs.splat.triton.projection import TRITON_PROJECTION

    scene = random_scene(4, seed=5, num_cameras=2, dtype=torch.float64)  # the interpreter is slow
    means, factors, opacities, viewmats, Ks, width, height = projection_inputs(scene)
    cameras = (viewmats, Ks, (width, height, 0.01, 1e10, 0.3))
    assert FusedProjectGaussians.apply(TRITON_PROJECTION, means, factors, opacities, *cameras)[
        4
    ].all()  # every pair visible, so every gradient path is checked

    def projected(means: torch.Tensor, factors: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = FusedProjectGaussians.apply(TRITON_PROJECTION, means, factors, opacities, *cameras)
        return out[:3]

    inputs = (means.requires_grad_(), factors.detach().requires_grad_())
    # fast mode checks random projections of the Jacobian: 3 kernel calls instead of ~150
    assert torch.autograd.gradcheck(projected, inputs, fast_mode=True)


RANDOM_CASES = {
    "rgb, one camera": ({"n": 60, "seed": 0}, {}),
    "two cameras, odd size, background": (
        {"n": 50, "seed": 1, "num_cameras": 2, "width": 13, "height": 11},
        {"backgrounds": torch.tensor([[0.2, 0.5, 0.1], [1.0, 0.0, 0.3]])},
    ),
    "five channels, tile 5": ({"n": 40, "seed": 2, "channels": 5}, {"tile_size": 5}),
    "antialiased": ({"n": 50, "seed": 6}, {"rasterize_mode": "antialiased"}),
    "rgb and depth": ({"n": 50, "seed": 3}, {"render_mode": "RGB+D"}),
    "depth only, tile 16": (
        {"n": 50, "seed": 4, "width": 20},
        {"render_mode": "D", "tile_size": 16},
    ),
}


@pytest.mark.parametrize(("scene_args", "options"), RANDOM_CASES.values(), ids=RANDOM_CASES)
def test_random_scenes_match_the_reference_and_the_torch_backend(scene_args, options):
    extra = ("backgrounds",) if "backgrounds" in options else ()
    scene = with_grad(
        {**random_scene(**{"width": 16, "height": 16, **scene_args}), **options}, extra
    )
    got = render_and_grads(rasterization, scene, backend="triton")
    assert got[2]["backend"] == "triton"
    reference = {k: v for k, v in scene.items() if k != "tile_size"}
    assert_render_matches(got, render_and_grads(rasterization_reference, reference), 1e-5, 1e-4)
    assert_render_matches(got, render_and_grads(rasterization, scene, backend="torch"), 1e-5, 1e-4)


def test_float64_matches_the_reference_to_rounding():
    """In float64 the batched transmittance products and their back-to-front division agree
    with the reference's autograd to rounding: the algebra, not just float32 closeness."""
    scene = with_grad(
        random_scene(60, seed=5, num_cameras=2, width=16, height=12, dtype=torch.float64)
    )
    sh = 0.3 * torch.randn(
        60, 4, 3, generator=torch.Generator().manual_seed(5), dtype=torch.float64
    )
    scene = with_grad({**scene, "colors": sh})
    options = {"sh_degree": 1, "render_mode": "RGB+D"}
    got = render_and_grads(rasterization, scene, backend="triton", **options)
    assert_render_matches(
        got, render_and_grads(rasterization_reference, scene, **options), 1e-12, 1e-9
    )


@pytest.mark.parametrize("hard", CULLED.values(), ids=CULLED.keys())
def test_a_culled_gaussian_is_finite_with_exactly_zero_gradient(hard):
    scene = with_grad(hard_scene(hard))
    colors, alphas, meta, grads = render_and_grads(rasterization, scene, backend="triton")
    assert torch.isfinite(colors).all() and torch.isfinite(alphas).all()
    assert meta["radii"][0, 2].tolist() == [0, 0]
    for key in LEARNABLE:
        assert torch.isfinite(grads[key]).all(), key
        assert torch.all(grads[key][2] == 0), f"culled Gaussian got a gradient on {key}"
        assert grads[key][:2].abs().sum() > 0, f"visible Gaussians lost their {key} gradient"


@pytest.mark.parametrize("hard", KEPT.values(), ids=KEPT.keys())
def test_a_hard_but_visible_gaussian_matches_the_reference(hard):
    scene = with_grad(hard_scene(hard, dtype=torch.float64))
    got = render_and_grads(rasterization, scene, backend="triton")
    expected = render_and_grads(rasterization_reference, scene)
    assert got[2]["radii"][0, 2].min() > 0
    torch.testing.assert_close(got[0], expected[0], rtol=0, atol=1e-9)
    torch.testing.assert_close(got[1], expected[1], rtol=0, atol=1e-9)
    for key in LEARNABLE:
        scale = max(1.0, expected[3][key].abs().max().item())
        torch.testing.assert_close(got[3][key], expected[3][key], rtol=1e-6, atol=1e-9 * scale)


def test_stacked_opaque_gaussians_stop_early_as_the_reference():
    """2,000 near-opaque Gaussians on one spot: pixels stop after a few, in the first batch,
    and the ones behind get exactly no gradient."""
    n = 2000
    gen = torch.Generator().manual_seed(0)
    _, Ks = camera_rig(1, HARD_WIDTH, HARD_HEIGHT)
    scene = with_grad(
        {
            "means": torch.tensor([0.0, 0.0, 3.0]) + torch.randn(n, 3, generator=gen) * 1e-3,
            "quats": torch.randn(n, 4, generator=gen),
            "scales": torch.tensor([0.03, 0.015, 0.01]).repeat(n, 1),
            "opacities": torch.full((n,), 0.999),
            "colors": torch.rand(n, 3, generator=gen),
            "viewmats": torch.eye(4)[None],
            "Ks": Ks,
            "width": HARD_WIDTH,
            "height": HARD_HEIGHT,
        }
    )
    got = render_and_grads(rasterization, scene, backend="triton")
    assert got[1][0, HARD_HEIGHT // 2, HARD_WIDTH // 2, 0] > 1 - 2e-4
    assert_render_matches(got, render_and_grads(rasterization_reference, scene), 1e-5, 1e-4)
    unused = got[3]["colors"].abs().sum(-1) == 0
    assert unused.sum() > n // 2
    by_torch = render_and_grads(rasterization, scene, backend="torch")[3]["colors"]
    assert torch.equal(unused, by_torch.abs().sum(-1) == 0)


def test_a_fixed_layer_renders_and_differentiates_as_the_full_scene():
    scene = random_scene(80, seed=6, width=16, height=16)
    mask = torch.arange(80) % 3 != 0
    alone = {**scene, "opacities": torch.where(mask, scene["opacities"], 0.0)}
    fixed_colors, fixed_alphas, _ = rasterization(**alone, backend="torch")
    fixed = FixedLayer(mask, fixed_colors, fixed_alphas)
    got = render_and_grads(rasterization, with_grad(scene), backend="triton", fixed=fixed)
    full = render_and_grads(rasterization, with_grad(scene), backend="torch")
    torch.testing.assert_close(got[0], full[0], rtol=0, atol=1e-5)
    torch.testing.assert_close(got[1], full[1], rtol=0, atol=1e-5)
    for key in LEARNABLE:
        assert torch.all(got[3][key][mask] == 0), key
        moving = full[3][key][~mask]
        assert (got[3][key][~mask] - moving).norm() / moving.norm() < 1e-4, key


def test_a_camera_mask_renders_and_differentiates_as_on_the_torch_backend():
    scene = random_scene(60, seed=9, num_cameras=2, width=16, height=16)
    mask = torch.ones(2, 60, dtype=torch.bool)
    mask[0, 40:] = mask[1, 20:40] = False
    got = render_and_grads(rasterization, with_grad(scene), backend="triton", camera_mask=mask)
    expected = render_and_grads(rasterization, with_grad(scene), backend="torch", camera_mask=mask)
    assert not got[2]["radii"][~mask].any()
    assert_render_matches(got, expected, 1e-5, 1e-4)


def test_triton_on_tensors_it_cannot_render_is_refused_with_the_cause():
    scene = {k: v.half() if torch.is_tensor(v) else v for k, v in random_scene(5).items()}
    with pytest.raises(InputError, match="float16"):
        rasterization(**scene, backend="triton")


def test_auto_on_cpu_tensors_keeps_the_cpu_backends():
    assert rasterization(**random_scene(5))[2]["backend"] in ("native", "torch")
