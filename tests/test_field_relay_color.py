"""relay_position's (1 + e^γ) factor and the per-camera ColorAffine."""

import math

import pytest
import torch

from relaygs.errors import InputError
from relaygs.field import GAMMA_LIMIT, LOG_GAIN_LIMIT, ColorAffine, relay_position


def test_relay_position_scales_only_relay_rows() -> None:
    generator = torch.Generator().manual_seed(0)
    mu = torch.randn(6, 3, generator=generator)
    dmu = torch.randn(6, 3, generator=generator)
    gamma = torch.randn(6, 3, generator=generator)
    is_relay = torch.tensor([True, False, True, False, False, True])
    moved = relay_position(mu, dmu, gamma, is_relay)
    torch.testing.assert_close(moved[is_relay], (mu + (1 + gamma.exp()) * dmu)[is_relay])
    assert torch.equal(moved[~is_relay], (mu + dmu)[~is_relay])
    mu, dmu = torch.zeros(2, 3), torch.ones(2, 3)  # γ = 0 doubles the relay motion
    moved = relay_position(mu, dmu, torch.zeros(2, 3), torch.tensor([True, False]))
    assert torch.equal(moved, torch.tensor([[2.0, 2.0, 2.0], [1.0, 1.0, 1.0]]))


def test_gamma_gradient_inside_range() -> None:
    gamma = torch.tensor([[0.5, -1.0, 2.0]], requires_grad=True)
    dmu = torch.tensor([[1.0, 2.0, -3.0]])
    relay_position(torch.zeros(1, 3), dmu, gamma, torch.tensor([True])).sum().backward()
    torch.testing.assert_close(gamma.grad, gamma.detach().exp() * dmu)


@pytest.mark.parametrize("value", [1e4, -1e4])
def test_huge_gamma_stays_finite(value: float) -> None:
    gamma = torch.full((2, 3), value, requires_grad=True)
    dmu = torch.ones(2, 3, requires_grad=True)
    moved = relay_position(torch.zeros(2, 3), dmu, gamma, torch.tensor([True, False]))
    moved.sum().backward()
    assert torch.isfinite(moved).all()
    assert torch.isfinite(gamma.grad).all() and torch.isfinite(dmu.grad).all()
    clamped = math.copysign(GAMMA_LIMIT, value)
    assert moved[0, 0].item() == pytest.approx(1 + math.exp(clamped))


def test_relay_position_shape_errors() -> None:
    with pytest.raises(InputError, match="one shape"):
        relay_position(torch.zeros(2, 3), torch.zeros(3, 3), torch.zeros(2, 3), torch.ones(2) > 0)
    with pytest.raises(InputError, match="is_relay: expected a bool tensor"):
        relay_position(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 3), torch.ones(2))


def test_color_affine_identity_at_init() -> None:
    affine = ColorAffine(4)
    image = torch.rand(5, 6, 3)
    assert torch.equal(affine(image, 2), image)
    batch = torch.rand(3, 5, 6, 3)
    assert torch.equal(affine(batch, torch.tensor([0, 3, 1])), batch)


def test_color_affine_applies_camera_parameters() -> None:
    affine = ColorAffine(3)
    with torch.no_grad():
        affine.log_gain[1] = torch.tensor([0.1, -0.2, 0.3])
        affine.offset[1] = torch.tensor([0.05, 0.0, -0.1])
    image = torch.rand(4, 4, 3)
    expected = image * torch.tensor([0.1, -0.2, 0.3]).exp() + torch.tensor([0.05, 0.0, -0.1])
    torch.testing.assert_close(affine(image, 1), expected)
    batch = torch.stack([image, image])
    out = affine(batch, torch.tensor([0, 1]))
    torch.testing.assert_close(out[0], image)
    torch.testing.assert_close(out[1], expected)
    out.sum().backward()
    assert affine.log_gain.grad[1].abs().sum().item() > 0.0
    assert torch.equal(affine.log_gain.grad[2], torch.zeros(3))


def test_color_affine_clamps_gain_and_checks_camera() -> None:
    affine = ColorAffine(2)
    with torch.no_grad():
        affine.log_gain.fill_(1e4)
    out = affine(torch.ones(2, 2, 3), 0)
    assert torch.isfinite(out).all()
    torch.testing.assert_close(out, torch.full((2, 2, 3), math.exp(LOG_GAIN_LIMIT)))
    with pytest.raises(InputError, match=r"indices in \[0, 1\]"):
        affine(torch.ones(2, 2, 3), 2)
    with pytest.raises(InputError, match="channel-last"):
        affine(torch.ones(3, 2, 2), 0)
