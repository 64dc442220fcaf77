"""Canonical forms of stage sections: settings that mean the same computation on a scene get one
spelling, which the artifact key hashes and the stage runs with (it must not change results)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from relaygs.data import Scene
from relaygs.train.segment_plan import boundaries_fixed

SectionCanonical = Callable[[Mapping[str, Any], Scene], dict[str, Any]]  # (section, scene)


def one_segment_at_most(section: Mapping[str, Any], scene: Scene) -> dict[str, Any]:
    """Segment length `k` capped at T: every k >= T is one segment of all frames."""
    canonical = dict(section)
    k = canonical.get("k")
    if isinstance(k, int) and not isinstance(k, bool) and k > scene.num_frames:
        canonical["k"] = scene.num_frames
    return canonical


def uniform_unless_adaptive(section: Mapping[str, Any], scene: Scene) -> dict[str, Any]:
    """`one_segment_at_most`, without `segments` where it is uniform or adaptive placement has no
    choice (k = 1 or k >= T), and without `segments_per_step` at 1, so relays keep the keys they
    had before those settings."""
    canonical = one_segment_at_most(section, scene)
    k = canonical.get("k")
    fixed = isinstance(k, int) and k >= 1 and boundaries_fixed(scene.num_frames, k)
    if canonical.get("segments", "uniform") == "uniform" or fixed:
        canonical.pop("segments", None)
    if canonical.get("segments_per_step", 1) == 1:
        canonical.pop("segments_per_step", None)
    return canonical


def deform_options_left_out_at_default(section: Mapping[str, Any], scene: Scene) -> dict[str, Any]:
    """`background_motion` left out where it is on or where one shared MLP set moves every
    Gaussian (`isolate_fg_bg` off ignores it), `matmul_dtype` where it is float32 and the hull
    term's weights, prefit steps and frame patches where they are 0 (and the patches' opacity
    with them), so deform artifacts keep the keys they had before those settings existed."""
    canonical = dict(section)
    if canonical.get("background_motion", True) or not canonical.get("isolate_fg_bg", True):
        canonical.pop("background_motion", None)
    if canonical.get("matmul_dtype", "float32") == "float32":
        canonical.pop("matmul_dtype", None)
    for key in ("hull_weight", "hull_coverage", "hull_prefit", "frame_patches"):
        if canonical.get(key, 0.0) == 0.0:
            canonical.pop(key, None)
    if "frame_patches" not in canonical:
        canonical.pop("patch_opacity", None)
    return canonical
