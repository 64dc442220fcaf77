"""The compiled Triton kernels on a GPU: `auto` takes them for CUDA tensors, and they match the
torch backend at real sizes and the dense reference in float64, hard cases and fixed layers
included. Skipped without CUDA (tools/gpu_check.sh runs this file on a GPU machine)."""

from __future__ import annotations

import importlib.util

import pytest
import torch

from relaygs.splat import FixedLayer, rasterization
from relaygs.splat.rasterize import select_backend
from relaygs.splat.reference import rasterization_reference
from splat_scenes import (
    CULLED,
    LEARNABLE,
    assert_grads_match,
    assert_render_matches,
    hard_scene,
    on_device,
    random_scene,
    render_and_grads,
    with_grad,
)

pytestmark = [
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"),
    pytest.mark.skipif(importlib.util.find_spec("triton") is None, reason="needs triton"),
]


@pytest.fixture(autouse=True, scope="module")
def compiled_kernels():
    """The kernels, compiled for the GPU (not in the interpreter)."""
    from relaygs.splat import triton as gpu

    if gpu.interpreted():
        pytest.skip("triton runs in its interpreter in this process (TRITON_INTERPRET=1)")


def _cuda(scene: dict, extra: tuple[str, ...] = ()) -> dict:
    return with_grad(on_device(scene, "cuda"), extra)


def test_auto_takes_the_triton_kernels_for_cuda_tensors():
    scene = on_device(random_scene(50), "cuda")
    assert rasterization(**scene)[2]["backend"] == "triton"
    half = scene["means"].half()  # float16: the torch path (which renders no float16 either)
    assert select_backend("auto", half).name == "torch"


@pytest.mark.parametrize(
    ("n", "cams", "size", "options"),
    [
        (10_000, 1, 256, {}),
        (20_000, 4, 128, {"backgrounds": torch.rand(4, 3)}),
        (5_000, 2, 160, {"render_mode": "RGB+D", "tile_size": 16}),
    ],
    ids=["10k-256", "20k-4cams-background", "depth-tile16"],
)
def test_real_sizes_match_the_torch_backend(n, cams, size, options):
    scene = random_scene(n, seed=n, num_cameras=cams, width=size, height=size)
    scene["scales"] = scene["scales"] * 0.3  # σ of a few pixels, as in bench splat
    scene = _cuda({**scene, **options}, ("backgrounds",) if "backgrounds" in options else ())
    got = render_and_grads(rasterization, scene, backend="triton")
    expected = render_and_grads(rasterization, scene, backend="torch")
    for mine, theirs in zip(got[:2], expected[:2], strict=True):
        # float32 transmittance, a batch's product against a pair-by-pair one, can cross the
        # early stop (1e-4) in one backend and not the other: such a pixel differs by that
        # one pair's weight, α·T < 0.99 · 1e-4 / 0.01 ≈ 1e-2; every other one to rounding
        # (relative, for depths of a few units).
        off = (mine - theirs).abs() > 1e-5 * (1 + theirs.abs())
        assert off.float().mean() < 1e-4 and (mine - theirs).abs().max() < 1e-2
    assert_grads_match(got, expected, 1e-3)


def test_float64_matches_the_reference_to_rounding():
    scene = random_scene(500, seed=9, num_cameras=2, width=64, height=48, dtype=torch.float64)
    scene = _cuda(scene)
    got = render_and_grads(rasterization, scene, backend="triton")
    assert_render_matches(got, render_and_grads(rasterization_reference, scene), 1e-12, 1e-9)


@pytest.mark.parametrize("hard", CULLED.values(), ids=CULLED.keys())
def test_a_culled_gaussian_gets_exactly_zero_gradient(hard):
    _, _, meta, grads = render_and_grads(rasterization, _cuda(hard_scene(hard)), backend="triton")
    assert meta["radii"][0, 2].tolist() == [0, 0]
    for key in LEARNABLE:
        assert torch.isfinite(grads[key]).all() and torch.all(grads[key][2] == 0), key


def test_a_fixed_layer_renders_as_the_full_scene():
    scene = on_device(random_scene(3000, seed=4, width=96, height=64), "cuda")
    mask = torch.arange(3000, device="cuda") % 4 != 0
    alone = {**scene, "opacities": torch.where(mask, scene["opacities"], 0.0)}
    fixed = FixedLayer(mask, *rasterization(**alone, backend="torch")[:2])
    got = render_and_grads(rasterization, with_grad(scene), backend="triton", fixed=fixed)
    full = render_and_grads(rasterization, with_grad(scene), backend="torch")
    torch.testing.assert_close(got[0], full[0], rtol=0, atol=1e-5)
    for key in LEARNABLE:
        assert torch.all(got[3][key][mask] == 0), key
        moving = full[3][key][~mask]
        assert (got[3][key][~mask] - moving).norm() / moving.norm() < 1e-4, key
