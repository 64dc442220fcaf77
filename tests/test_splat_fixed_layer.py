"""A FixedLayer gives the same image and moving gradients as a full render, with less work."""

from __future__ import annotations

from dataclasses import fields, replace

import pytest
import torch

from relaygs.errors import InputError
from relaygs.splat import FixedLayer, rasterization
from relaygs.splat.projection import Projection
from splat_scenes import random_scene, render_and_grads, with_grad

# Every test here runs on both backends (the `splat_backend` fixture in conftest).
pytestmark = pytest.mark.usefixtures("splat_backend")

MOVING = 12  # the last rows move; the rest are fixed
PROJECTION_FIELDS = tuple(f.name for f in fields(Projection))


def _scene(dtype: torch.dtype = torch.float32) -> dict:
    """Fixed Gaussians everywhere, a few small moving ones gathered in one corner."""
    scene = random_scene(160, seed=7, num_cameras=3, width=64, height=48, dtype=dtype)
    gen = torch.Generator().manual_seed(8)
    scene["means"][-MOVING:, :2] = 0.45 + 0.2 * torch.rand(MOVING, 2, generator=gen, dtype=dtype)
    scene["scales"][-MOVING:] = 0.03
    scene["backgrounds"] = torch.rand(3, 3, generator=gen, dtype=dtype)
    return scene


def _mask(scene: dict) -> torch.Tensor:
    mask = torch.ones(scene["means"].shape[0], dtype=torch.bool)
    mask[-MOVING:] = False
    return mask


def _layer(scene: dict, with_projection: bool = False) -> FixedLayer:
    """The fixed rows rendered alone (the moving ones hidden by zero opacity); optionally with
    the fixed rows' projection and features from that render's meta."""
    mask = _mask(scene)
    alone = {**scene, "backgrounds": None, "opacities": scene["opacities"] * mask}
    colors, alphas, meta = rasterization(**alone)
    if not with_projection:
        return FixedLayer(mask, colors, alphas)
    rows = {name: meta[name][:, mask] for name in (*PROJECTION_FIELDS, "features")}
    projection = Projection(**{name: rows[name] for name in PROJECTION_FIELDS})
    return FixedLayer(mask, colors, alphas, projection, rows["features"])


@pytest.mark.parametrize("with_projection", [False, True])
def test_fixed_layer_matches_the_full_render(with_projection):
    scene = _scene(torch.float64)
    layer = _layer(scene, with_projection)
    full = render_and_grads(rasterization, with_grad(scene, ("backgrounds",)))
    fast = render_and_grads(rasterization, with_grad(scene, ("backgrounds",)), fixed=layer)
    torch.testing.assert_close(fast[0], full[0], rtol=0, atol=1e-10)
    torch.testing.assert_close(fast[1], full[1], rtol=0, atol=1e-10)
    moving = ~layer.mask
    for key in ("means", "quats", "scales", "opacities", "colors"):
        expected, got = full[3][key], fast[3][key]
        assert expected[moving].abs().max() > 0, key
        torch.testing.assert_close(got[moving], expected[moving], rtol=1e-8, atol=1e-12)
        assert not got[layer.mask].any(), f"{key}: fixed rows must get zero gradients"
    torch.testing.assert_close(fast[3]["backgrounds"], full[3]["backgrounds"])


def test_tiles_only_fixed_gaussians_touch_are_copied_from_the_layer():
    scene = _scene()
    real = _layer(scene)
    marker = FixedLayer(
        real.mask, torch.full_like(real.colors, 0.25), torch.full_like(real.alphas, 0.5)
    )
    colors, alphas, _ = rasterization(**{**scene, "backgrounds": None}, fixed=marker)
    copied = (colors == 0.25).all(dim=-1)
    # Most tiles hold no moving Gaussian and come from the layer; the moving corner is rendered.
    assert copied.float().mean() > 0.5
    assert (~copied).any()
    assert bool((alphas[copied] == 0.5).all())
    assert bool(copied[:, 0, 0].all()), "the corner away from the moving Gaussians is copied"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda layer: FixedLayer(layer.mask[1:], layer.colors, layer.alphas), "fixed.mask"),
        (lambda layer: FixedLayer(layer.mask.float(), layer.colors, layer.alphas), "fixed.mask"),
        (lambda layer: FixedLayer(layer.mask, layer.colors[:1], layer.alphas), "fixed.colors"),
        (lambda layer: FixedLayer(layer.mask, layer.colors, layer.colors), "fixed.alphas"),
        (lambda layer: replace(layer, features=layer.features[:, 1:]), "fixed.features"),
        (
            lambda layer: replace(
                layer, projection=replace(layer.projection, bounds=layer.projection.bounds[:1])
            ),
            "fixed.projection.bounds",
        ),
    ],
)
def test_bad_fixed_layers_raise_one_line_errors(change, message):
    scene = _scene()
    with pytest.raises(InputError, match=message) as error:
        rasterization(**scene, fixed=change(_layer(scene, with_projection=True)))
    assert "\n" not in str(error.value)


def test_fixed_layers_need_rgb_mode():
    scene = _scene()
    with pytest.raises(InputError, match="render_mode 'RGB'"):
        rasterization(**scene, fixed=_layer(scene), render_mode="RGB+D")
