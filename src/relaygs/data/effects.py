"""Names of the effects a scene declares (scene.json or the `effects` option); training switches
modules on from them, and a synthetic scene simulates exactly those."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from relaygs.errors import InputError

LARGE_MOTION = "large_motion"  # actors travel many times their own size during the sequence
NONRIGID = "nonrigid"  # articulated actors swing their limbs: the body deforms
FAST_OBJECTS = "fast_objects"  # small objects (balls) move fast, several times their size per frame
COLOR_INCONSISTENCY = "color_inconsistency"  # a per-camera, per-channel gain and offset
DYNAMIC_PANELS = "dynamic_panels"  # background panels (a scoreboard) change their content over time
BACKGROUND_JITTER = "background_jitter"  # background objects (spectators) move slightly over time
SENSOR_NOISE = "sensor_noise"  # independent per-pixel Gaussian noise in every image

ALL_EFFECTS: frozenset[str] = frozenset(
    {
        LARGE_MOTION,
        NONRIGID,
        FAST_OBJECTS,
        COLOR_INCONSISTENCY,
        DYNAMIC_PANELS,
        BACKGROUND_JITTER,
        SENSOR_NOISE,
    }
)
NO_EFFECTS = "none"
"""Given alone instead of effect names, it declares no effects (`--effects none`,
`scene.effects=none`), as an empty list does."""


def parse_effects(names: Iterable[str], *, source: str) -> frozenset[str]:
    """Effect names (one, a list, or NO_EFFECTS alone for none) checked; errors name `source`."""
    if isinstance(names, str):
        names = [names]
    if isinstance(names, Mapping) or not isinstance(names, Iterable):  # e.g. `effects=3`
        raise InputError(f"{source}: expected an effect name or a list of them, got {names!r}")
    names = list(names)
    if names == [NO_EFFECTS]:
        return frozenset()
    for name in names:
        if not isinstance(name, str) or name not in ALL_EFFECTS:
            raise InputError(
                f"{source}: unknown effect {name!r}; expected one of: "
                f"{', '.join(sorted(ALL_EFFECTS))} (or '{NO_EFFECTS}' alone for no effects)"
            )
    return frozenset(names)
