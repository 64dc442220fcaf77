"""Synthetic multi-view video scenes rendered by analytic ray casting, simulating only the
effects they declare (see `relaygs.data.effects`); `generate` writes the Panoptic layout."""

from relaygs.data.effects import ALL_EFFECTS
from relaygs.data.synthetic.generate import (
    GENERATOR_VERSION,
    MAX_SYNTH_COUNT,
    declared_effects,
    generate,
    remove_abandoned_staging,
    require_valid_preset,
    rig_cameras,
)
from relaygs.data.synthetic.presets import PRESETS

__all__ = [
    "ALL_EFFECTS",
    "GENERATOR_VERSION",
    "MAX_SYNTH_COUNT",
    "PRESETS",
    "declared_effects",
    "generate",
    "remove_abandoned_staging",
    "require_valid_preset",
    "rig_cameras",
]
