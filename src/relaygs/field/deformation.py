"""DeformationField: one HexPlane and one MLP set for all Gaussians, or two (background, fg)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from relaygs.errors import InputError
from relaygs.field.hexplane import HexPlane
from relaygs.field.mlp import DeformationMLP, Deltas, HeadSwitches

SHARED_SET = "all"
ISOLATED_SETS = ("background", "foreground")


class DeformationField(nn.Module):
    """Motion field (xyz, t) → Deltas; with `isolate_fg_bg` background and foreground rows go
    through separate MLP sets (the paper's) reading one shared HexPlane, and without
    `background_motion` the background keeps still (no background set, zero deltas)."""

    def __init__(
        self,
        aabb: Tensor | Sequence[Sequence[float]],
        time_resolution: int,
        *,
        isolate_fg_bg: bool = True,
        background_motion: bool = True,
        multires: Sequence[int] = (1, 2),
        spatial_resolution: int = 64,
        channels: int = 16,
        width: int = 128,
        depth: int = 0,
        heads: HeadSwitches = HeadSwitches(),  # noqa: B008 - frozen, immutable default
        matmul_dtype: str = "float32",
    ) -> None:
        """Build the grid over `aabb` ([2, 3]) with `time_resolution` rows and the MLP set(s)
        (their matrix products in `matmul_dtype`, DeformationMLP)."""
        super().__init__()
        self.hexplane = HexPlane(
            aabb,
            time_resolution,
            multires=multires,
            spatial_resolution=spatial_resolution,
            channels=channels,
        )
        self.isolate_fg_bg = isolate_fg_bg
        self.background_motion = background_motion or not isolate_fg_bg
        names = ISOLATED_SETS if isolate_fg_bg else (SHARED_SET,)
        if not self.background_motion:
            names = ("foreground",)
        self.mlp_sets = nn.ModuleDict(
            {
                name: DeformationMLP(
                    self.hexplane.feature_dim,
                    width=width,
                    depth=depth,
                    heads=heads,
                    matmul_dtype=matmul_dtype,
                )
                for name in names
            }
        )

    def forward(self, xyz: Tensor, t: float | Tensor, num_background: int) -> Deltas:
        """Deltas of Gaussians at `xyz` [N, 3], time `t` in [0, 1] (scalar or [N]): the first
        `num_background` rows background, the rest foreground (a host count: no device read)."""
        if not 0 <= num_background <= xyz.shape[0]:
            raise InputError(
                f"DeformationField num_background: expected 0..{xyz.shape[0]}, got {num_background}"
            )
        if not self.isolate_fg_bg:
            return self.mlp_sets[SHARED_SET](self.hexplane(xyz, t))
        if not self.background_motion:
            # a still background: the field runs on the foreground rows alone
            times = t[num_background:] if torch.is_tensor(t) and t.dim() else t
            moving = self.mlp_sets["foreground"](self.hexplane(xyz[num_background:], times))
            return Deltas(
                *(torch.cat([d.new_zeros(num_background, d.shape[1]), d]) for d in moving)
            )
        features = self.hexplane(xyz, t)
        halves = (
            self.mlp_sets["background"](features[:num_background]),
            self.mlp_sets["foreground"](features[num_background:]),
        )
        return Deltas(*(torch.cat(pair) for pair in zip(*halves, strict=True)))

    def foreground_set(self) -> DeformationMLP:
        """The MLP set that moves the foreground rows (the shared one without isolation)."""
        return self.mlp_sets["foreground" if self.isolate_fg_bg else SHARED_SET]

    def regularisers(self) -> dict[str, Tensor]:
        """The HexPlane's unweighted regularisers (plane_smoothness, time_smoothness, time_l1)."""
        return self.hexplane.regularisers()

    def parameter_groups(self) -> dict[str, list[nn.Parameter]]:
        """Parameters split for optimiser groups: "grid" (planes) and "mlp" (all MLP sets)."""
        return {
            "grid": list(self.hexplane.parameters()),
            "mlp": list(self.mlp_sets.parameters()),
        }
