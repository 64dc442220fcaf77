"""The motion field: HexPlane grid, deformation MLPs, relay γ update, per-camera colour affine."""

from relaygs.field.color_affine import LOG_GAIN_LIMIT, ColorAffine
from relaygs.field.deformation import DeformationField
from relaygs.field.gamma import GAMMA_LIMIT, relay_position
from relaygs.field.hexplane import HexPlane
from relaygs.field.mlp import DeformationMLP, Deltas, HeadSwitches

__all__ = [
    "GAMMA_LIMIT",
    "LOG_GAIN_LIMIT",
    "ColorAffine",
    "DeformationField",
    "DeformationMLP",
    "Deltas",
    "HeadSwitches",
    "HexPlane",
    "relay_position",
]
