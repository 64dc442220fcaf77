"""Stage renders with a frozen part: FrozenRenders gives the full render's image and gradients."""

from __future__ import annotations

import pytest
import torch

from relaygs.data import Camera
from relaygs.model import GaussianSet
from relaygs.train.render import FrozenRenders, part_of, screen_statistics, slot_mask, splat
from splat_scenes import dome_cameras

EPS2D = 0.3  # screen blur of these renders (px², the rasterizer's default)

WIDTH, HEIGHT = 64, 36


def _sets() -> tuple[GaussianSet, GaussianSet]:
    """A background spread over the scene and a small foreground near its centre."""
    gen = torch.Generator().manual_seed(3)
    sets = []
    for count, spread, opacity in ((400, 2.0, 0.4), (30, 0.2, 0.6)):
        xyz = (torch.rand(count, 3, generator=gen) - 0.5) * spread
        colors = torch.rand(count, 3, generator=gen)
        sets.append(GaussianSet.from_points(xyz, colors, max_sh_degree=1, init_opacity=opacity))
    return sets[0], sets[1]


def _render_and_grads(frozen: FrozenRenders | None, antialiased: bool = False):
    background, foreground = _sets()
    parts = [part_of("bg", background, 1, frozen=True), part_of("fg", foreground, 1)]
    cameras = dome_cameras(WIDTH, HEIGHT)[:3]
    render = splat(parts, cameras, 1, frozen, eps2d=EPS2D, antialiased=antialiased)
    weights = torch.linspace(-1.0, 1.0, WIDTH * 3).repeat(HEIGHT, 1).view(HEIGHT, WIDTH, 3)
    sum(((image * weights).sum() for image in render.images), torch.zeros(())).backward()
    grads = {name: param.grad for name, param in foreground.params.items()}
    return render, grads, screen_statistics(render, "fg")


@pytest.mark.parametrize("antialiased", [False, True])
def test_splat_with_frozen_renders_matches_a_full_splat(antialiased):
    full, full_grads, full_stats = _render_and_grads(None, antialiased)
    fast, fast_grads, fast_stats = _render_and_grads(FrozenRenders(EPS2D, antialiased), antialiased)
    for got, expected in zip(fast.images + fast.alphas, full.images + full.alphas, strict=True):
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-5)
    for name, expected in full_grads.items():
        torch.testing.assert_close(fast_grads[name], expected, rtol=1e-3, atol=1e-6)
    # (isotropic Gaussians get no rotation gradient)
    assert all(full_grads[name].abs().max() > 0 for name in ("means", "log_scales", "sh_dc"))
    torch.testing.assert_close(fast_stats[0], full_stats[0], rtol=1e-3, atol=1e-7)
    assert torch.equal(fast_stats[1], full_stats[1])


def test_frozen_parts_are_rendered_once_per_camera():
    background, foreground = _sets()
    cameras = dome_cameras(WIDTH, HEIGHT)[:3]
    frozen = FrozenRenders(EPS2D)

    def render() -> torch.Tensor:
        parts = [part_of("bg", background, 1, frozen=True), part_of("fg", foreground, 1)]
        return torch.stack(splat(parts, cameras, 1, frozen, eps2d=EPS2D).images).detach()

    first = render()
    background.params["sh_dc"].data.zero_()  # breaks the contract: the cache does not see it
    assert torch.equal(render(), first)
    fresh = torch.stack(
        splat([part_of("bg", background, 1, frozen=True)], cameras, 1, eps2d=EPS2D).images
    )
    assert not torch.equal(fresh.detach(), first)
    cameras[0] = Camera(0, cameras[0].K, cameras[1].w2c, WIDTH, HEIGHT)  # same id, new pose
    parts = [part_of("bg", background, 1, frozen=True), part_of("fg", foreground, 1)]
    uncached = splat(parts, cameras[:1], 1, eps2d=EPS2D).images[0].detach()
    torch.testing.assert_close(render()[0], uncached, rtol=0, atol=1e-5)  # rendered again


def test_all_frozen_or_all_trainable_parts_render_without_a_layer():
    background, foreground = _sets()
    cameras = dome_cameras(WIDTH, HEIGHT)[:3]
    for frozen_fg in (True, False):
        parts = [
            part_of("bg", background, 1, frozen=frozen_fg),
            part_of("fg", foreground, 1, frozen=frozen_fg),
        ]
        plain = splat(parts, cameras, 1, eps2d=EPS2D).images
        cached = FrozenRenders(EPS2D)
        assert all(
            torch.equal(a, b)
            for a, b in zip(
                splat(parts, cameras, 1, cached, eps2d=EPS2D).images, plain, strict=True
            )
        )
        assert not cached._cache, "no frozen/trainable mix: nothing to cache"


def test_a_cached_frozen_render_does_not_depend_on_the_cameras_batched_with_it():
    """A resumed stage's empty cache first renders a camera beside others than the whole run
    did: the cache must hold the same bits either way, or the resumed stage drifts."""
    background, foreground = _sets()
    cameras = dome_cameras(WIDTH, HEIGHT)[:3]
    parts = [part_of("bg", background, 1, frozen=True), part_of("fg", foreground, 1)]
    together, one_by_one = FrozenRenders(EPS2D), FrozenRenders(EPS2D)
    batched = together.layer(parts, cameras, 1)
    for camera in reversed(cameras):
        one_by_one.layer(parts, [camera], 1)
    alone = one_by_one.layer(parts, cameras, 1)
    assert torch.equal(batched.colors, alone.colors)
    assert torch.equal(batched.alphas, alone.alphas)
    assert torch.equal(batched.features, alone.features)


def test_one_masked_render_of_several_copies_equals_one_render_per_copy():
    """A relay step with several segments: cameras 0–1 see copy A (foreground rows 0–14),
    camera 2 copy B (rows 15–29), all of them the frozen background; one masked render gives
    each camera's image, the copies' gradients and their screen statistics of one render each."""
    background, foreground = _sets()
    cameras = dome_cameras(WIDTH, HEIGHT)[:3]
    slots = [(cameras[:2], torch.arange(15)), (cameras[2:], torch.arange(15, 30))]
    weights = torch.linspace(-1.0, 1.0, WIDTH * 3).repeat(HEIGHT, 1).view(HEIGHT, WIDTH, 3)

    def backward(images: list[torch.Tensor]) -> dict[str, torch.Tensor]:
        for param in foreground.params.values():
            param.grad = None
        sum(((image * weights).sum() for image in images), torch.zeros(())).backward()
        return {name: param.grad.clone() for name, param in foreground.params.items()}

    frozen = FrozenRenders(EPS2D)
    background_part = part_of("bg", background, 1, frozen=True)
    rows = torch.cat([copy for _, copy in slots])
    mask = slot_mask(len(background), [(len(views), len(copy)) for views, copy in slots])
    shown = part_of("fg", foreground, 1, rows=rows)
    joint = splat([background_part, shown], cameras, 1, frozen, mask, eps2d=EPS2D)
    joint_grads = backward(joint.images)
    joint_stats = screen_statistics(joint, "fg")

    images, renders = [], []
    for views, copy in slots:
        render = splat(
            [background_part, part_of("fg", foreground, 1, rows=copy)],
            views,
            1,
            frozen,
            eps2d=EPS2D,
        )
        images += render.images
        renders.append(render)
    separate_grads = backward(images)
    for got, expected in zip(joint.images, images, strict=True):
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-6)
    for name, expected in separate_grads.items():
        torch.testing.assert_close(joint_grads[name], expected, rtol=1e-4, atol=1e-7)
    assert all(separate_grads[name].abs().max() > 0 for name in ("means", "log_scales", "sh_dc"))
    for index, render in enumerate(renders):
        grad, radii, _ = screen_statistics(render, "fg")
        cams = slice(0, 2) if index == 0 else slice(2, 3)
        block = slice(0, 15) if index == 0 else slice(15, 30)
        assert torch.equal(joint_stats[1][cams, block], radii)
        torch.testing.assert_close(joint_stats[0][cams, block], grad, rtol=1e-4, atol=1e-9)
        others = slice(15, 30) if index == 0 else slice(0, 15)
        assert not joint_stats[1][cams, others].any(), "a camera must not see another's copy"
