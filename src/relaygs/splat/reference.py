"""Dense reference renderer: every Gaussian at every pixel, plain autograd, same numerics.

Slow (O(C·N·H·W) memory) and obviously correct: depth sort, per-pixel cumulative
product of (1 − α), the 3DGS skip and early-stop rules written out directly. Tests
compare the fast path against it.
"""

from __future__ import annotations

from typing import Any

import torch

from relaygs.splat.composite import ALPHA_MAX, T_MIN
from relaygs.splat.projection import ALPHA_MIN
from relaygs.splat.rasterize import blur_compensation, finish_depth, prepare

PIXEL_CHUNK = 1024


def _render_camera(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    bounds: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    background: torch.Tensor | None,
    width: int,
    height: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One camera: colors [H,W,D] and alpha [H,W,1]."""
    idx = torch.nonzero(visible).squeeze(1)
    idx = idx[torch.argsort(depths[idx], stable=True)]
    ys, xs = torch.meshgrid(
        torch.arange(height, device=means2d.device),
        torch.arange(width, device=means2d.device),
        indexing="ij",
    )
    pixels = torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)
    # Pixels are independent: evaluate them in chunks to bound memory.
    parts = [
        _render_pixels(chunk, means2d[idx], conics[idx], opacities[idx], colors[idx], bounds[idx])
        for chunk in pixels.split(PIXEL_CHUNK)
    ]
    image = torch.cat([part[0] for part in parts])
    t_final = torch.cat([part[1] for part in parts])
    if background is not None:
        image = image + t_final * background[None]
    return image.reshape(height, width, -1), (1.0 - t_final).reshape(height, width, 1)


def _render_pixels(
    pixels: torch.Tensor,
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    bounds: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite depth-sorted Gaussians at integer pixels [P,2]: colours [P,D], T_final [P,1]."""
    xs, ys = pixels[:, 0], pixels[:, 1]
    dx = (xs.to(means2d.dtype) + 0.5)[None] - means2d[:, 0:1]  # [n, P]
    dy = (ys.to(means2d.dtype) + 0.5)[None] - means2d[:, 1:2]
    power = (
        0.5 * conics[:, 0:1] * dx * dx + conics[:, 1:2] * dx * dy + 0.5 * conics[:, 2:3] * dy * dy
    )
    inside = (
        (xs[None] >= bounds[:, 0:1])
        & (xs[None] <= bounds[:, 1:2])
        & (ys[None] >= bounds[:, 2:3])
        & (ys[None] <= bounds[:, 3:4])
    )
    power = torch.where(inside, power, torch.zeros_like(power))
    alpha = torch.clamp(opacities[:, None] * torch.exp(-power), max=ALPHA_MAX)
    keep = inside & (power >= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    one_minus = 1.0 - alpha
    trans_after = torch.cumprod(one_minus, dim=0)
    trans_before = torch.cat([torch.ones_like(trans_after[:1]), trans_after[:-1]], dim=0)
    included = keep & (trans_after >= T_MIN)
    weight = torch.where(included, alpha * trans_before, torch.zeros_like(alpha))
    t_final = torch.where(included, one_minus, torch.ones_like(one_minus)).prod(dim=0)
    return weight.transpose(0, 1) @ colors, t_final[:, None]


def rasterization_reference(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    backgrounds: torch.Tensor | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    render_mode: str = "RGB",
    rasterize_mode: str = "classic",
) -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
    """`relaygs.splat.rasterization`'s images and alphas, computed densely (no tiles, no
    FixedLayer); its meta holds only `means2d`, `radii` and `depths`."""
    prep = prepare(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        sh_degree=sh_degree, backgrounds=backgrounds, near_plane=near_plane,
        far_plane=far_plane, eps2d=eps2d, render_mode=render_mode,
    )  # fmt: skip
    proj = prep.proj
    opac = opacities[None].expand(viewmats.shape[0], -1)
    if rasterize_mode == "antialiased":
        opac = opac * blur_compensation(proj.conics, eps2d)
    images, alphas = [], []
    for cam in range(viewmats.shape[0]):
        img, alpha = _render_camera(
            proj.means2d[cam], proj.conics[cam], opac[cam], prep.features[cam], proj.bounds[cam],
            proj.depths[cam], proj.visible[cam],
            None if prep.backgrounds is None else prep.backgrounds[cam], width, height,
        )  # fmt: skip
        images.append(img)
        alphas.append(alpha)
    colors_out, alphas_out = torch.stack(images), torch.stack(alphas)
    meta = {"means2d": proj.means2d, "radii": proj.radii, "depths": proj.depths}
    return finish_depth(colors_out, alphas_out, render_mode), alphas_out, meta
