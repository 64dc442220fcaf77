"""Error images: the mean absolute error over channels through the colour map, saturating at
the full scale."""

import torch
from matplotlib import colormaps

from refusals import refused
from relaygs.error_map import COLOUR_MAP, ERROR_FULL_SCALE, error_image


def _colour(fraction: float) -> torch.Tensor:
    """The colour map's colour at `fraction` of its range, sampled independently of the module."""
    rgba = colormaps[COLOUR_MAP](round(fraction * 255) / 255)
    return torch.tensor(rgba[:3], dtype=torch.float32)


def test_the_error_is_averaged_over_channels_through_the_map_and_saturates():
    truth = torch.zeros(1, 6, 3)
    render = torch.zeros(1, 6, 3)
    render[0, 0] = torch.tensor([ERROR_FULL_SCALE * 1.5, 0.0, 0.0])  # mean: half the scale
    render[0, 1] = ERROR_FULL_SCALE / 4  # a quarter of the scale in every channel
    render[0, 2] = -ERROR_FULL_SCALE / 4  # the sign does not matter
    render[0, 3] = 1.0  # far beyond the scale
    render[0, 4, 0] = float("nan")  # not a number: the largest error
    render[0, 5] = float("inf")
    image = error_image(render, truth)
    for pixel, fraction in ((0, 0.5), (1, 0.25), (2, 0.25), (3, 1.0), (4, 1.0), (5, 1.0)):
        assert torch.allclose(image[0, pixel], _colour(fraction), atol=1e-6), pixel
    render = torch.rand(4, 5, 3, generator=torch.Generator().manual_seed(0))
    assert torch.allclose(error_image(render, render), _colour(0.0).expand(4, 5, 3), atol=1e-6)
    brighter = (render + ERROR_FULL_SCALE).clamp(max=2.0)
    assert torch.allclose(error_image(render, brighter), _colour(1.0).expand(4, 5, 3), atol=1e-6)
    # in between, brightness grows with the error
    truth = torch.zeros(1, 11, 3)
    render = torch.linspace(0, ERROR_FULL_SCALE, 11).view(1, 11, 1).expand(1, 11, 3)
    luminance = error_image(render, truth)[0] @ torch.tensor([0.2126, 0.7152, 0.0722])
    assert bool((luminance.diff() > 0).all())
    # images of other shapes are refused
    with refused(ValueError, "[2, 2, 3]", "[2, 3, 3]"):
        error_image(torch.zeros(2, 2, 3), torch.zeros(2, 3, 3))
