"""Real scene content: the shared Mip-NeRF 360 garden asset (gsplat's test protocol)."""

from __future__ import annotations

import pytest
import torch

from relaygs.commands.bench_splat import GARDEN_PATH, garden_case
from relaygs.splat import rasterization
from relaygs.splat.projection import covariance_factor, project_gaussians
from relaygs.splat.reference import rasterization_reference

# Every test here runs on both backends (the `splat_backend` fixture in conftest).
pytestmark = [
    pytest.mark.usefixtures("splat_backend"),
    pytest.mark.skipif(
        not GARDEN_PATH.is_file(), reason=f"{GARDEN_PATH} not found (shared data absent)"
    ),
]


@pytest.fixture(scope="module")
def garden() -> dict:
    return garden_case()


def test_garden_renders_finite_with_coverage(garden):
    with torch.no_grad():
        colors, alphas, meta = rasterization(**garden)
    assert colors.shape == (3, 420, 648, 3)
    assert torch.isfinite(colors).all() and torch.isfinite(alphas).all()
    for cam in range(3):
        assert alphas[cam].mean() > 0.5, f"camera {cam}: alpha coverage {alphas[cam].mean():.2f}"
    assert meta["num_pairs"] > 100_000


def test_garden_crop_matches_reference(garden):
    """A 64×64 crop of camera 0 (principal point shifted), fast path against the dense one."""
    x_off, y_off, size = 292, 178, 64
    Ks = garden["Ks"][:1].clone()
    Ks[0, 0, 2] -= x_off
    Ks[0, 1, 2] -= y_off
    crop = {**garden, "viewmats": garden["viewmats"][:1], "Ks": Ks, "width": size, "height": size}
    with torch.no_grad():
        proj = project_gaussians(
            crop["means"],
            covariance_factor(crop["quats"], crop["scales"]),
            crop["opacities"],
            crop["viewmats"],
            Ks,
            size,
            size,
        )
        seen = proj.visible[0]
        subset = {
            **crop,
            **{k: crop[k][seen] for k in ("means", "quats", "scales", "opacities", "colors")},
        }
        colors, alphas, _ = rasterization(**crop)
        ref_colors, ref_alphas, _ = rasterization_reference(**subset)
    assert seen.sum() > 1000, "the crop holds real depth complexity"
    torch.testing.assert_close(colors, ref_colors, rtol=0, atol=1e-5)
    torch.testing.assert_close(alphas, ref_alphas, rtol=0, atol=1e-5)
