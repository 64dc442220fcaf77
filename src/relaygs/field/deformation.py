"""DeformationField: one HexPlane and one MLP set for all Gaussians, or two (background, fg)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from relaygs.errors import InputError
from relaygs.field.hexplane import HexPlane
from relaygs.field.mlp import HEAD_WIDTHS, DeformationMLP, Deltas, HeadSwitches

BACKGROUND = 0
FOREGROUND = 1
SHARED_SET = "all"
ISOLATED_SETS = ("background", "foreground")


class DeformationField(nn.Module):
    """Motion field (xyz, t, group) → Deltas; with `isolate_fg_bg` background (group 0) and
    foreground (1) go through separate MLP sets (the paper's) reading one shared HexPlane, and
    without `background_motion` the background keeps still (no background set, zero deltas)."""

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
    ) -> None:
        """Build the grid over `aabb` ([2, 3]) with `time_resolution` rows and the MLP set(s)."""
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
                    self.hexplane.feature_dim, width=width, depth=depth, heads=heads
                )
                for name in names
            }
        )

    def forward(self, xyz: Tensor, t: float | Tensor, group: Tensor | None = None) -> Deltas:
        """Deltas of Gaussians at `xyz` [N, 3], time `t` in [0, 1] (scalar or [N]); `group` [N]
        is required with isolated MLP sets and ignored otherwise."""
        if not self.isolate_fg_bg:
            return self.mlp_sets[SHARED_SET](self.hexplane(xyz, t))
        group = _validated_group(group, xyz.shape[0])
        if not bool((group[1:] < group[:-1]).any()):
            # background rows first (as the stages lay them out): slices instead of gathers
            return self.forward_split(xyz, t, int((group == BACKGROUND).sum()))
        features = self.hexplane(xyz, t)
        parts = []
        for value, name in ((BACKGROUND, "background"), (FOREGROUND, "foreground")):
            if name in self.mlp_sets:
                rows = torch.nonzero(group == value).squeeze(1)
                parts.append((rows, self.mlp_sets[name](features.index_select(0, rows))))
        return _scatter_rows(xyz.shape[0], parts)

    def forward_split(self, xyz: Tensor, t: float | Tensor, num_background: int) -> Deltas:
        """`forward` for background-first rows, their count given on the host (no device read)."""
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

    def regularisers(self) -> dict[str, Tensor]:
        """The HexPlane's unweighted regularisers (plane_smoothness, time_smoothness, time_l1)."""
        return self.hexplane.regularisers()

    def parameter_groups(self) -> dict[str, list[nn.Parameter]]:
        """Parameters split for optimiser groups: "grid" (planes) and "mlp" (all MLP sets)."""
        return {
            "grid": list(self.hexplane.parameters()),
            "mlp": list(self.mlp_sets.parameters()),
        }


def _validated_group(group: Tensor | None, count: int) -> Tensor:
    if group is None:
        raise InputError("DeformationField group: required when isolate_fg_bg is true, got None")
    if group.shape != (count,) or group.is_floating_point() or group.is_complex():
        raise InputError(
            f"DeformationField group: expected an integer or bool tensor of shape [{count}], "
            f"got {group.dtype} {list(group.shape)}"
        )
    group = group.long()
    if count and bool(((group != BACKGROUND) & (group != FOREGROUND)).any()):
        raise InputError(
            "DeformationField group: expected values 0 (background) or 1 (foreground), got "
            f"{sorted(set(group.unique().tolist()))}"
        )
    return group


def _scatter_rows(count: int, parts: list[tuple[Tensor, Deltas]]) -> Deltas:
    """Full [count, ·] deltas from (row indices, deltas of those rows) pairs; other rows get 0."""
    like = parts[0][1].dxyz
    fields = []
    for name, out_width in HEAD_WIDTHS.items():
        out = like.new_zeros(count, out_width)
        for rows, deltas in parts:
            out = out.index_copy(0, rows, getattr(deltas, name))
        fields.append(out)
    return Deltas(*fields)
