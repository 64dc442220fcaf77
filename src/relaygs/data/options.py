"""Loader options shared by every format, validated once, with the part that enters fingerprints."""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from relaygs.data.effects import parse_effects
from relaygs.errors import InputError

DEFAULT_MAX_POINTS = 100_000
DEFAULT_CACHE_MB = 512.0
OPTION_PREFIX = "loader option "  # errors say `loader option downscale`; the app its own keys


@dataclass(frozen=True)
class LoaderOptions:
    """Options of `load_scene`; `effects=None` takes the scene's own declaration (scene.json)."""

    downscale: int = 1
    max_points: int = DEFAULT_MAX_POINTS
    cache_mb: float = DEFAULT_CACHE_MB
    test_cameras: tuple[int, ...] | None = None
    effects: frozenset[str] | None = None
    prefix: str = field(default=OPTION_PREFIX, compare=False)  # how errors name the options

    def content_options(self) -> dict[str, Any]:
        """The options that change what a scene holds (everything but the cache budget)."""
        return {
            "max_points": self.max_points,
            "test_cameras": None if self.test_cameras is None else list(self.test_cameras),
            "effects": None if self.effects is None else sorted(self.effects),
        }


def make_options(
    *,
    downscale: int = 1,
    max_points: int = DEFAULT_MAX_POINTS,
    cache_mb: float = DEFAULT_CACHE_MB,
    test_cameras: Iterable[int] | None = None,
    effects: Iterable[str] | None = None,
    prefix: str = OPTION_PREFIX,
) -> LoaderOptions:
    """Raw option values checked into LoaderOptions; errors name `prefix` + the option."""
    downscale = require_int("downscale", downscale, minimum=1, prefix=prefix)
    max_points = require_int("max_points", max_points, minimum=1, prefix=prefix)
    # a budget in whole bytes: one whose byte count is infinite has none (memory is finite)
    number = not isinstance(cache_mb, bool) and isinstance(cache_mb, int | float)
    if not number or not 0 < cache_mb * 2**20 < math.inf:
        raise InputError(f"{prefix}cache_mb must be a finite number > 0, got {cache_mb!r}")
    cameras = None
    if test_cameras is not None:
        if isinstance(test_cameras, str | bytes) or not isinstance(test_cameras, Iterable):
            raise InputError(f"{prefix}test_cameras must be a list of ids, got {test_cameras!r}")
        ids = {
            require_int("test_cameras entry", camera_id, minimum=0, prefix=prefix)
            for camera_id in test_cameras
        }
        cameras = tuple(sorted(ids))
    declared = None if effects is None else parse_effects(effects, source=f"{prefix}effects")
    return LoaderOptions(downscale, max_points, float(cache_mb), cameras, declared, prefix)


INT64_MAX = 2**63 - 1
"""The largest int torch and numpy take as a size or seed (a larger one is a traceback)."""


def require_int(
    name: str,
    value: object,
    *,
    minimum: int,
    prefix: str = OPTION_PREFIX,
    maximum: int = INT64_MAX,
) -> int:
    """`value` as an int in [minimum, maximum], else an InputError naming `prefix` + `name`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise InputError(f"{prefix}{name} must be an integer >= {minimum}, got {value!r}")
    if value > maximum:
        raise InputError(f"{prefix}{name} must be an integer <= {maximum}, got {value!r}")
    return int(value)


def test_cameras_setting(ids: Sequence[int] | None) -> str:
    """How a user sets the held-out cameras to `ids` (None: a placeholder), as loader errors
    suggest it: a run's scene.loader.test_cameras, the artifacts commands' --test-cameras."""
    listed = "ID,..." if ids is None else ",".join(str(camera_id) for camera_id in ids)
    flag = listed or "'[]'"
    return f"scene.loader.test_cameras=[{listed}] (artifacts commands: --test-cameras {flag})"
