"""Named step budgets: overrides merged over the stage sections (and `train`) by the app.

`paper` is the defaults (3000 / 14000 / 20000 steps). `small` runs the default pipeline on
the default synthetic scene (160×90, 64 frames) in about a quarter of an hour on a 2-core
CPU: fewer steps, the density schedule compressed to fit, a Gaussian cap. `smoke` is a few
steps of every code path (densify, prune, opacity reset, SH growth) for tests.
"""

from __future__ import annotations

from typing import Any


def _densify(start: int, every: int, until: int, reset: int, cap: int) -> dict[str, int]:
    return {
        "densify_from": start,
        "densify_every": every,
        "densify_until": until,
        "opacity_reset_every": reset,
        "max_gaussians": cap,
    }


_SMOKE_DENSIFY = _densify(start=4, every=4, until=16, reset=12, cap=3000)
_SMALL_STATIC = _densify(start=100, every=50, until=400, reset=250, cap=12_000)

BUDGETS: dict[str, dict[str, dict[str, Any]]] = {
    "paper": {},
    "small": {
        "decouple": {
            "steps": 500,
            "init_points": 10_000,
            "sh_every": 150,
            "densify": _SMALL_STATIC,
        },
        "warmup": {"steps": 500, "init_points": 10_000, "sh_every": 150, "densify": _SMALL_STATIC},
        "relay": {
            "steps": 300,
            "sh_every": 100,
            "densify_fg": _densify(start=100, every=50, until=250, reset=0, cap=6000),
        },
        "deform": {
            "steps": 600,
            "sh_every": 200,
            "densify_bg": _densify(start=100, every=100, until=450, reset=0, cap=12_000),
            "densify_fg": _densify(start=100, every=100, until=450, reset=0, cap=6000),
        },
    },
    "smoke": {
        "train": {"log_every": 5, "checkpoint_every": 10, "progress": False},
        "decouple": {
            "steps": 20,
            "init_points": 1500,
            "sh_every": 8,
            "densify": _SMOKE_DENSIFY,
        },
        "warmup": {"steps": 20, "init_points": 1500, "sh_every": 8, "densify": _SMOKE_DENSIFY},
        "relay": {"steps": 20, "sh_every": 8, "densify_fg": _SMOKE_DENSIFY},
        "deform": {
            "steps": 20,
            "sh_every": 8,
            "spatial_resolution": 16,
            "width": 32,
            "densify_bg": _SMOKE_DENSIFY,
            "densify_fg": _SMOKE_DENSIFY,
        },
    },
}
