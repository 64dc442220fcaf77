"""Deformation MLP: HexPlane features → per-Gaussian deltas of position, scale, rotation, opacity.

Layout follows 4D-GS: a trunk, then one head per attribute (ReLU→Linear(W,W)→ReLU→Linear).
The deltas add to the pre-activation Gaussian parameters; there is no SH head.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import NamedTuple

import torch
from torch import Tensor, nn

from relaygs.errors import InputError


class Deltas(NamedTuple):
    """Per-Gaussian offsets to pre-activation parameters.

    dxyz [N,3], dscale [N,3] (log-scale), drot [N,4] (wxyz quaternion), dopacity [N,1] (logit).
    """

    dxyz: Tensor
    dscale: Tensor
    drot: Tensor
    dopacity: Tensor


HEAD_WIDTHS = {"dxyz": 3, "dscale": 3, "drot": 4, "dopacity": 1}


@dataclass(frozen=True)
class HeadSwitches:
    """Which heads predict a delta (4D-GS no_dx/no_ds/no_dr/no_do, inverted); off gives zeros."""

    dxyz: bool = True
    dscale: bool = True
    drot: bool = True
    dopacity: bool = True


def _head(width: int, out: int) -> nn.Sequential:
    last = nn.Linear(width, out)
    # Zero weights and bias in the last layer: the deform stage starts from the trained
    # static model, so the initial deformation must be exactly the identity (4D-GS gives
    # every Linear Xavier weights, so its initial deformation is random).
    nn.init.zeros_(last.weight)
    nn.init.zeros_(last.bias)
    return nn.Sequential(nn.ReLU(), nn.Linear(width, width), nn.ReLU(), last)


class DeformationMLP(nn.Module):
    """Trunk Linear(feature_dim, W) plus `depth` ReLU→Linear(W, W) layers, then the enabled heads.

    4D-GS's multi-view config (defor_depth 0, net_width 128) is a single trunk Linear: depth 0.
    """

    def __init__(
        self,
        feature_dim: int,
        *,
        width: int = 128,
        depth: int = 0,
        heads: HeadSwitches = HeadSwitches(),
    ) -> None:
        """Build the trunk and one head per switched-on attribute."""
        super().__init__()
        if feature_dim < 1 or width < 1 or depth < 0:
            raise InputError(
                "DeformationMLP: expected feature_dim >= 1, width >= 1, depth >= 0, got "
                f"{feature_dim}, {width}, {depth}"
            )
        layers: list[nn.Module] = [nn.Linear(feature_dim, width)]
        for _ in range(depth):
            layers += [nn.ReLU(), nn.Linear(width, width)]
        self.trunk = nn.Sequential(*layers)
        self.heads = nn.ModuleDict(
            {name: _head(width, HEAD_WIDTHS[name]) for name, on in asdict(heads).items() if on}
        )

    def forward(self, features: Tensor) -> Deltas:
        """Deltas for features [N, feature_dim]; a switched-off head returns zeros."""
        # Every head starts with ReLU(hidden): apply it once and run the heads' remaining layers
        # (same values and parameters; saves three of the heads' largest element-wise ops).
        shared = torch.relu(self.trunk(features))
        count = features.shape[0]
        return Deltas(
            **{
                name: self.heads[name][1:](shared)
                if name in self.heads
                else features.new_zeros(count, out)
                for name, out in HEAD_WIDTHS.items()
            }
        )
