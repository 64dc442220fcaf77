"""Relay position update: relay Gaussians move by (1 + e^γ)·Δμ, the rest by Δμ (RelayGS eq.)."""

from __future__ import annotations

import torch
from torch import Tensor

from relaygs.errors import InputError

# γ is clamped to ±GAMMA_LIMIT before exp so the factor stays ≤ 1 + e^10 ≈ 2.2e4 and never
# overflows; inside the range the gradient is the exact one.
GAMMA_LIMIT = 10.0


def relay_position(mu: Tensor, dmu: Tensor, gamma: Tensor, is_relay: Tensor) -> Tensor:
    """Deformed centres [N, 3]: μ + (1 + e^clamp(γ))·Δμ for relay Gaussians (2·Δμ at γ = 0, as
    the paper's formula at initialisation), μ + Δμ for the others."""
    if mu.shape != dmu.shape or mu.shape != gamma.shape:
        raise InputError(
            "relay_position: expected mu, dmu, gamma of one shape [N, 3], got "
            f"{list(mu.shape)}, {list(dmu.shape)}, {list(gamma.shape)}"
        )
    if gamma.dim() != 2 or gamma.shape[1] != 3:
        raise InputError(f"relay gamma: expected shape [N, 3], got {list(gamma.shape)}")
    if is_relay.shape != (gamma.shape[0],) or is_relay.dtype != torch.bool:
        raise InputError(
            f"relay is_relay: expected a bool tensor of shape [{gamma.shape[0]}], "
            f"got {is_relay.dtype} {list(is_relay.shape)}"
        )
    boosted = 1.0 + torch.exp(gamma.clamp(-GAMMA_LIMIT, GAMMA_LIMIT))
    return mu + torch.where(is_relay.unsqueeze(1), boosted, torch.ones_like(boosted)) * dmu
