"""Apply the motion field at one time to the background and the shown foreground rows: deltas
add to the pre-activation parameters; with γ, foreground positions move by (1 + e^γ)·Δμ."""

from __future__ import annotations

import torch
from torch import Tensor

from relaygs.field import DeformationField, relay_position
from relaygs.model import GaussianSet
from relaygs.train.render import Part, part_of
from relaygs.train.scene_model import GAMMA


def deformed_parts(
    background: GaussianSet,
    foreground: GaussianSet,
    foreground_rows: Tensor,
    field: DeformationField,
    time: float,
    sh_degree: int,
) -> list[Part]:
    """Background and foreground Parts at `time` in [0, 1], with γ where the set has it."""
    bg = part_of("bg", background, sh_degree)
    fg = part_of("fg", foreground, sh_degree, rows=foreground_rows)
    n_bg = bg.count
    xyz = torch.cat([bg.means, fg.means])
    deltas = field(xyz, time, n_bg)  # the counts are known here: no device read
    if GAMMA in foreground.params:
        gamma = foreground.select_rows(GAMMA, foreground_rows)
        gammas = torch.cat([gamma.new_zeros(n_bg, 3), gamma])
        is_relay = torch.arange(xyz.shape[0], device=xyz.device) >= n_bg
        means = relay_position(xyz, deltas.dxyz, gammas, is_relay)
    else:
        means = xyz + deltas.dxyz
    log_scales = torch.cat([bg.log_scales, fg.log_scales]) + deltas.dscale
    quats = torch.cat([bg.quats, fg.quats]) + deltas.drot
    opacity_logits = torch.cat([bg.opacity_logits, fg.opacity_logits]) + deltas.dopacity[:, 0]
    return [
        Part(p.name, p.rows, means[r], log_scales[r], quats[r], opacity_logits[r], p.sh)
        for p, r in ((bg, slice(0, n_bg)), (fg, slice(n_bg, None)))
    ]


def foreground_means(
    xyz: Tensor, gamma: Tensor | None, field: DeformationField, time: float
) -> Tensor:
    """Deformed centres [R, 3] of foreground Gaussians at `xyz` (γ `gamma`, or None) at `time`,
    without the background: what a geometric target of the movers needs."""
    dxyz = field(xyz, time, 0).dxyz
    if gamma is None:
        return xyz + dxyz
    is_relay = torch.ones(len(xyz), dtype=torch.bool, device=xyz.device)
    return relay_position(xyz, dxyz, gamma, is_relay)
