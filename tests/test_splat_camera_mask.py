"""`camera_mask`: one render that shows each camera its own rows equals one render per camera."""

from __future__ import annotations

import pytest
import torch

from relaygs.errors import InputError
from relaygs.splat import rasterization
from relaygs.train.render import slot_mask
from splat_scenes import LEARNABLE, random_scene, with_grad

# Every test here runs on both backends (the `splat_backend` fixture in conftest).
pytestmark = pytest.mark.usefixtures("splat_backend")

SHARED, OWN = 40, 12  # rows every camera sees; rows each of the three cameras sees alone
CAMERAS = 3


def _scene() -> dict:
    return random_scene(SHARED + CAMERAS * OWN, seed=3, num_cameras=CAMERAS, dtype=torch.float64)


def _rows_of(camera: int) -> torch.Tensor:
    """The shared rows, then the camera's own block."""
    start = SHARED + camera * OWN
    return torch.cat([torch.arange(SHARED), torch.arange(start, start + OWN)])


def _alone(scene: dict, camera: int) -> dict:
    """The scene as camera `camera` alone sees it: its rows, its view."""
    rows = _rows_of(camera)
    out = {key: scene[key][rows] for key in LEARNABLE}
    out.update(viewmats=scene["viewmats"][camera : camera + 1], Ks=scene["Ks"][camera : camera + 1])
    return {**scene, **out}


def test_slot_mask_shows_each_camera_the_shared_rows_and_its_own_block() -> None:
    mask = slot_mask(2, [(2, 1), (1, 3)])
    expected = [
        [1, 1, 1, 0, 0, 0],
        [1, 1, 1, 0, 0, 0],
        [1, 1, 0, 1, 1, 1],
    ]
    assert torch.equal(mask, torch.tensor(expected, dtype=torch.bool))


def _loss(colors: torch.Tensor, alphas: torch.Tensor, camera: int, seed: int) -> torch.Tensor:
    """A fixed random weighing (by `seed`) of camera `camera`'s image and alphas."""
    gen = torch.Generator().manual_seed(seed)
    w_colors = torch.randn(colors.shape[1:], generator=gen, dtype=colors.dtype)
    w_alphas = torch.randn(alphas.shape[1:], generator=gen, dtype=alphas.dtype)
    return (colors[camera] * w_colors).sum() + (alphas[camera] * w_alphas).sum()


@pytest.mark.parametrize("camera", range(CAMERAS))
def test_a_masked_render_equals_one_render_per_camera(camera: int) -> None:
    """Camera `camera`'s image, radii and gradients from the joint masked render are those of
    a render of its own rows alone; rows it does not see get no gradient from it."""
    scene = with_grad(_scene())
    mask = slot_mask(SHARED, [(1, OWN)] * CAMERAS)
    colors, alphas, meta = rasterization(**scene, camera_mask=mask)
    assert not meta["radii"][~mask].any(), "masked-out rows must be culled"
    grads = torch.autograd.grad(
        _loss(colors, alphas, camera, seed=camera), [scene[k] for k in LEARNABLE]
    )

    alone = with_grad(_alone(scene, camera))
    colors_1, alphas_1, meta_1 = rasterization(**alone)
    torch.testing.assert_close(colors[camera], colors_1[0], rtol=0, atol=1e-10)
    torch.testing.assert_close(alphas[camera], alphas_1[0], rtol=0, atol=1e-10)
    rows = _rows_of(camera)
    assert torch.equal(meta["radii"][camera, rows], meta_1["radii"][0])
    expected = torch.autograd.grad(
        _loss(colors_1, alphas_1, 0, seed=camera), [alone[k] for k in LEARNABLE]
    )
    unseen = torch.ones(SHARED + CAMERAS * OWN, dtype=torch.bool)
    unseen[rows] = False
    for key, got, want in zip(LEARNABLE, grads, expected, strict=True):
        assert want.abs().max() > 0, key
        torch.testing.assert_close(got[rows], want, rtol=1e-9, atol=1e-12)
        assert not got[unseen].any(), f"{key}: rows camera {camera} does not see"


@pytest.mark.parametrize(
    "mask", [torch.ones(CAMERAS, 5, dtype=torch.bool), torch.ones(CAMERAS, SHARED + 3 * OWN)]
)
def test_a_mask_of_the_wrong_shape_or_type_is_refused(mask: torch.Tensor) -> None:
    with pytest.raises(InputError, match="camera_mask"):
        rasterization(**_scene(), camera_mask=mask)
