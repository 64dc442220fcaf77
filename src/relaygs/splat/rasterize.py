"""`rasterization`: the one functional entry of the splatting core (gsplat-style API)."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from relaygs.errors import InputError
from relaygs.splat import native
from relaygs.splat import triton as gpu
from relaygs.splat.composite import CompositeGaussians, FixedLayer
from relaygs.splat.native.binning import bin_gaussians_native
from relaygs.splat.native.composite import NativeCompositeGaussians
from relaygs.splat.native.projection import project_gaussians_native
from relaygs.splat.projection import (
    ALPHA_MIN,
    MAX_FOCAL,
    Projection,
    covariance_factor,
    project_gaussians,
)
from relaygs.splat.sh import eval_sh, num_sh_bases
from relaygs.splat.tiles import (
    DEFAULT_TILE_SIZE,
    TileBins,
    bin_gaussians,
    bin_gaussians_all_tiles,
    only_tiles,
    tiles_touched_by,
)
from relaygs.splat.triton.composite import TritonCompositeGaussians
from relaygs.splat.triton.projection import project_gaussians_triton

RENDER_MODES = ("RGB", "D", "RGB+D")
RASTERIZE_MODES = ("classic", "antialiased")
MIN_KEPT_AREA = 1e-8
"""Smallest det(Σ)/det(Σ + eps2d·I) whose square root `blur_compensation` differentiates: its
gradient 0.5/√x stays below 5e3 (a Gaussian this flat on screen is compensated to ≤ 1e-4)."""
BACKENDS = ("auto", "torch", "native", "triton")
MIN_NEAR_PLANE = 1e-9
"""Smallest near plane: the projection's backward divides by depth², and fx/depth² stays a
finite float32 for any focal length below 1e20 (scenes' near planes are >= 1.1e-8)."""


def _check(cond: bool, message: str) -> None:
    if not cond:
        raise InputError(message)


def validate_inputs(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int | None,
    backgrounds: torch.Tensor | None,
    render_mode: str,
) -> None:
    """Raise InputError with a one-line message for any shape or value that does not fit."""
    n = means.shape[0] if means.dim() == 2 else -1
    _check(
        means.dim() == 2 and means.shape[1] == 3, f"means must be [N,3], got {list(means.shape)}"
    )
    _check(quats.shape == (n, 4), f"quats must be [{n},4], got {list(quats.shape)}")
    _check(scales.shape == (n, 3), f"scales must be [{n},3], got {list(scales.shape)}")
    _check(opacities.shape == (n,), f"opacities must be [{n}], got {list(opacities.shape)}")
    _check(
        viewmats.dim() == 3 and viewmats.shape[1:] == (4, 4),
        f"viewmats must be [C,4,4], got {list(viewmats.shape)}",
    )
    c = viewmats.shape[0]
    _check(Ks.shape == (c, 3, 3), f"Ks must be [{c},3,3], got {list(Ks.shape)}")
    focal = Ks[:, [0, 1], [0, 1]]
    good = torch.isfinite(Ks).flatten(1).all(1) & ((focal > 0) & (focal <= MAX_FOCAL)).all(1)
    if not bool(good.all()):  # one read from the device
        bad = int((~good).nonzero()[0, 0])
        raise InputError(
            f"Ks must be finite with focal lengths fx, fy in (0, {MAX_FOCAL:.0e}], got camera "
            f"{bad}'s {Ks[bad].tolist()}"
        )
    _check(width > 0 and height > 0, f"width and height must be positive, got {width}x{height}")
    _check(
        render_mode in RENDER_MODES,
        f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}",
    )
    if sh_degree is None:
        _check(
            colors.dim() in (2, 3)
            and colors.shape[-2] == n
            and colors.shape[-1] >= 1
            and (colors.dim() == 2 or colors.shape[0] == c),
            f"colors must be [N,D] or [C,N,D] with N={n}, C={c}, D>=1, got {list(colors.shape)}",
        )
    else:
        _check(0 <= sh_degree <= 3, f"sh_degree must be 0..3, got {sh_degree}")
        k = num_sh_bases(sh_degree)
        _check(
            colors.dim() == 3
            and colors.shape[0] == n
            and colors.shape[1] >= k
            and colors.shape[2] == 3,
            f"SH colors must be [{n},K>={k},3] for sh_degree {sh_degree}, got {list(colors.shape)}",
        )
    if backgrounds is not None:
        d = 3 if sh_degree is not None else colors.shape[-1]
        _check(
            backgrounds.shape == (c, d),
            f"backgrounds must be [{c},{d}], got {list(backgrounds.shape)}",
        )


def validate_planes(near_plane: float, far_plane: float, eps2d: float) -> None:
    """Raise InputError unless MIN_NEAR_PLANE <= near_plane < far_plane and eps2d is finite
    and >= 0 (the projection's backward divides by depth², which must not underflow)."""
    _check(
        MIN_NEAR_PLANE <= near_plane < far_plane,
        f"near_plane and far_plane must satisfy {MIN_NEAR_PLANE:.2g} <= near_plane < far_plane, "
        f"got {near_plane} and {far_plane}",
    )
    _check(0.0 <= eps2d < math.inf, f"eps2d must be finite and >= 0, got {eps2d}")


def camera_colors(
    means: torch.Tensor, colors: torch.Tensor, viewmats: torch.Tensor, sh_degree: int | None
) -> torch.Tensor:
    """Per-camera colour features [C,N,D]: SH evaluated along each camera's view directions."""
    c = viewmats.shape[0]
    if sh_degree is None:
        return colors.expand(c, *colors.shape[-2:]) if colors.dim() == 2 else colors
    rot, trans = viewmats[:, :3, :3], viewmats[:, :3, 3]
    centres = -torch.einsum("cji,cj->ci", rot, trans)  # camera centres in world space
    dirs = means[None] - centres[:, None]
    norm = torch.linalg.vector_norm(dirs, dim=-1, keepdim=True)
    dirs = dirs / torch.where(norm > 0, norm, torch.ones_like(norm))
    return eval_sh(sh_degree, colors, dirs)


@dataclass
class Prepared:
    """Projected Gaussians and per-camera features, shared by the fast and reference paths."""

    proj: Projection
    features: torch.Tensor  # [C,N,D'] colours, plus a depth channel in depth modes
    backgrounds: torch.Tensor | None  # [C,D'] with 0 for the depth channel


def prepare(
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
    sh_degree: int | None,
    backgrounds: torch.Tensor | None,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    render_mode: str,
    fixed: FixedLayer | None = None,
    project: Callable[..., Projection] = project_gaussians,
) -> Prepared:
    """Validate, project (with `project`, a backend's `project_gaussians`), and build the
    features every render mode composites.

    The rows a FixedLayer `fixed` marks are prepared without autograd (they get no
    gradient), so the backward of projection and SH covers only the other rows; its
    projection and features, when given, are used instead of computing them.
    """
    validate_inputs(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        sh_degree, backgrounds, render_mode,
    )  # fmt: skip
    validate_planes(near_plane, far_plane, eps2d)
    shade = functools.partial(
        _project_and_shade, viewmats=viewmats, Ks=Ks, width=width, height=height,
        sh_degree=sh_degree, render_mode=render_mode, near_plane=near_plane,
        far_plane=far_plane, eps2d=eps2d, project=project,
    )  # fmt: skip
    inputs = (means, quats, scales, opacities, colors)
    if fixed is None or bool(fixed.mask.all()) or not bool(fixed.mask.any()):
        proj, features = shade(*inputs)
    else:
        color_dim = 1 if sh_degree is None and colors.dim() == 3 else 0
        rows = (fixed.mask.nonzero().squeeze(1), (~fixed.mask).nonzero().squeeze(1))
        if fixed.projection is not None and fixed.features is not None:
            still = fixed.projection, fixed.features
        else:
            with torch.no_grad():
                still = shade(*_select_rows(inputs, rows[0], color_dim))
        moving = shade(*_select_rows(inputs, rows[1], color_dim))
        proj, features = _merge_rows(means.shape[0], rows, (still, moving))
    bg = backgrounds
    if bg is not None and render_mode != "RGB":
        depth_bg = bg.new_zeros(viewmats.shape[0], 1)
        bg = depth_bg if render_mode == "D" else torch.cat([bg, depth_bg], dim=-1)
    return Prepared(proj, features, bg)


def _project_and_shade(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    *,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int | None,
    render_mode: str,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    project: Callable[..., Projection],
) -> tuple[Projection, torch.Tensor]:
    """The projection and the features [C,N,D'] of the mode (colours, then depth)."""
    proj = project(
        means,
        covariance_factor(quats, scales),
        opacities,
        viewmats,
        Ks,
        width,
        height,
        near_plane,
        far_plane,
        eps2d,
    )
    features = []
    if render_mode != "D":
        features.append(camera_colors(means, colors, viewmats, sh_degree))
    if render_mode != "RGB":
        features.append(proj.depths[..., None])
    return proj, torch.cat(features, dim=-1)


def _select_rows(
    inputs: tuple[torch.Tensor, ...], rows: torch.Tensor, color_dim: int
) -> list[torch.Tensor]:
    """The per-Gaussian inputs (means, quats, scales, opacities, colors) at `rows`."""
    *per_row, colors = inputs
    return [t.index_select(0, rows) for t in per_row] + [colors.index_select(color_dim, rows)]


def _merge_rows(
    n: int,
    rows: tuple[torch.Tensor, torch.Tensor],
    pieces: tuple[tuple[Projection, torch.Tensor], tuple[Projection, torch.Tensor]],
) -> tuple[Projection, torch.Tensor]:
    """One projection and feature tensor over all N rows from two disjoint row sets."""

    def merged(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        out = second.new_zeros(second.shape[0], n, *second.shape[2:])
        return out.index_copy(1, rows[0], first).index_copy(1, rows[1], second)

    (proj_a, features_a), (proj_b, features_b) = pieces
    values = {
        f.name: merged(getattr(proj_a, f.name), getattr(proj_b, f.name))
        for f in dataclasses.fields(Projection)
    }
    return Projection(**values), merged(features_a, features_b)


def validate_fixed(
    fixed: FixedLayer, n: int, c: int, width: int, height: int, channels: int, render_mode: str
) -> None:
    """Raise InputError unless `fixed` fits N Gaussians rendered as RGB into C cameras."""
    _check(render_mode == "RGB", f"fixed layers need render_mode 'RGB', got {render_mode!r}")
    _check(
        fixed.mask.shape == (n,) and fixed.mask.dtype == torch.bool,
        f"fixed.mask must be [{n}] bool, got {fixed.mask.dtype} {list(fixed.mask.shape)}",
    )
    _check(
        fixed.colors.shape == (c, height, width, channels),
        f"fixed.colors must be [{c},{height},{width},{channels}], got {list(fixed.colors.shape)}",
    )
    _check(
        fixed.alphas.shape == (c, height, width, 1),
        f"fixed.alphas must be [{c},{height},{width},1], got {list(fixed.alphas.shape)}",
    )
    if fixed.projection is None or fixed.features is None:
        return
    f = int(fixed.mask.sum())
    for name in [field.name for field in dataclasses.fields(Projection)]:
        shape = list(getattr(fixed.projection, name).shape)
        _check(shape[:2] == [c, f], f"fixed.projection.{name} must be [{c},{f},...], got {shape}")
    shape = list(fixed.features.shape)
    _check(shape == [c, f, channels], f"fixed.features must be [{c},{f},{channels}], got {shape}")


def _moving_tiles(bins: TileBins, fixed: FixedLayer | None) -> TileBins:
    """Bins whose groups hold only the tiles some non-fixed Gaussian touches."""
    if fixed is None:
        return bins
    return only_tiles(bins, tiles_touched_by(bins, ~fixed.mask))


def _leave_out(proj: Projection, camera_mask: torch.Tensor | None) -> Projection:
    """The projection with Gaussian n culled in camera c wherever camera_mask[c, n] is False:
    binning skips it there, so it composites nothing and gets no gradient from that camera."""
    if camera_mask is None:
        return proj
    shape = tuple(proj.visible.shape)
    _check(
        camera_mask.shape == shape and camera_mask.dtype == torch.bool,
        f"camera_mask must be {list(shape)} bool, got {camera_mask.dtype} "
        f"{list(camera_mask.shape)}",
    )
    keep = proj.visible & camera_mask.to(proj.visible.device)
    radii = torch.where(keep[..., None], proj.radii, torch.zeros_like(proj.radii))
    return dataclasses.replace(proj, visible=keep, radii=radii)


def blur_compensation(conics: torch.Tensor, eps2d: float) -> torch.Tensor:
    """√(det Σ / det(Σ + eps2d·I)) [C,N] from the blurred conics [C,N,3] (Mip-Splatting's 2D
    filter): the opacity factor that keeps a blurred Gaussian's screen integral, so that a
    sub-pixel Gaussian spreads to a pixel's footprint without growing brighter. With (a, b, c)
    the conic of B = Σ + εI, det Σ / det B = 1 − ε(a + c) + ε²(ac − b²), evaluated as
    (1 − εa)(1 − εc) − (εb)²: in float32 within 1e-4 relative down to a factor of 1e-3, where
    the expanded sum of four terms near 1 loses 1e-3 (culled rows: 1)."""
    a, b, c = conics.unbind(-1)
    kept = (1.0 - eps2d * a) * (1.0 - eps2d * c) - (eps2d * b) ** 2
    return kept.clamp(MIN_KEPT_AREA, 1.0).sqrt()


def finish_depth(render: torch.Tensor, alphas: torch.Tensor, render_mode: str) -> torch.Tensor:
    """Turn the accumulated-depth channel into expected depth (0 where nothing was hit).

    Any hit has alpha >= 1/255, so the division is well conditioned.
    """
    if render_mode == "RGB":
        return render
    hit = alphas > ALPHA_MIN * 0.5
    depth = torch.where(hit, render[..., -1:] / torch.where(hit, alphas, 1.0), 0.0)
    return depth if render_mode == "D" else torch.cat([render[..., :-1], depth], dim=-1)


@dataclass(frozen=True)
class Backend:
    """How one backend projects, bins and composites (the signatures of
    `project_gaussians`, `bin_gaussians` and `CompositeGaussians`)."""

    name: str
    project: Callable[..., Projection]
    bin: Callable[..., TileBins]
    composite: type[torch.autograd.Function]


TORCH_BACKEND = Backend("torch", project_gaussians, bin_gaussians, CompositeGaussians)
NATIVE_BACKEND = Backend(
    "native", project_gaussians_native, bin_gaussians_native, NativeCompositeGaussians
)
TRITON_BACKEND = Backend(
    "triton", project_gaussians_triton, bin_gaussians_all_tiles, TritonCompositeGaussians
)


_default_backend = "auto"


def use_backend(backend: str) -> None:
    """Set the backend that `rasterization(backend=None)` uses in this process (a run's
    `splat.backend`); "native" is checked here, so a run that cannot have it stops before
    any work with one line naming the cause."""
    global _default_backend
    _check(backend in BACKENDS, f"splat.backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "native":
        try:
            native.load()
        except native.NativeUnavailableError as err:
            raise InputError(f"splat.backend 'native' is unavailable: {err}") from err
    _check(
        backend != "triton" or gpu.available(),
        "splat.backend 'triton' is unavailable: triton does not import here",
    )
    _default_backend = backend


def default_backend() -> str:
    """The backend `rasterization(backend=None)` uses ("auto" unless `use_backend` set one)."""
    return _default_backend


def select_backend(backend: str, like: torch.Tensor) -> Backend:
    """The backend `backend` names, for tensors like `like`.

    "auto" takes the Triton kernels for CUDA float tensors where triton imports, the native
    kernels for CPU float tensors when they build (the first failure prints one line why)
    and the torch path otherwise; "native" and "triton" raise InputError naming the cause
    where their kernels cannot run.
    """
    _check(backend in BACKENDS, f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "torch":
        return TORCH_BACKEND
    if backend == "triton":
        return _triton_backend(like)
    if backend == "auto":
        if like.device.type == "cuda" and gpu.available() and gpu.supports(like):
            return TRITON_BACKEND
        ok = native.supports(like) and native.available()
        return NATIVE_BACKEND if ok else TORCH_BACKEND
    _check(
        native.supports(like),
        f"backend 'native' renders float32/float64 CPU tensors, got {like.dtype} on "
        f"{like.device.type}",
    )
    try:
        native.load()
    except native.NativeUnavailableError as err:
        raise InputError(f"backend 'native' is unavailable: {err}") from err
    return NATIVE_BACKEND


def native_kernels_in_use(like: torch.Tensor) -> bool:
    """Whether the process default backend takes the native kernels for tensors like `like`
    (other native kernels, such as the deformation field's, follow the same switch)."""
    return select_backend(default_backend(), like) is NATIVE_BACKEND


def _triton_backend(like: torch.Tensor) -> Backend:
    """The Triton backend, or InputError naming why it cannot render tensors like `like`."""
    _check(gpu.available(), "backend 'triton' is unavailable: triton does not import here")
    _check(
        gpu.supports(like),
        f"backend 'triton' renders float32/float64 CUDA tensors (CPU ones in Triton's "
        f"interpreter), got {like.dtype} on {like.device.type}",
    )
    return TRITON_BACKEND


def rasterization(
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
    tile_size: int = DEFAULT_TILE_SIZE,
    fixed: FixedLayer | None = None,
    camera_mask: torch.Tensor | None = None,
    backend: str | None = None,
    rasterize_mode: str = "classic",
) -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
    """Render N Gaussians into C cameras; returns colors [C,H,W,D], alphas [C,H,W,1], meta.

    means [N,3]; quats [N,4] wxyz of any norm; scales [N,3] activated; opacities [N] in
    [0,1]; colors [N,D] / [C,N,D] features, or SH [N,K,3] with `sh_degree`; viewmats
    [C,4,4] world→camera (OpenCV axes); Ks [C,3,3]. Mode "D" renders expected depth,
    "RGB+D" appends it as the last channel. `meta["means2d"]` [C,N,2] holds the
    screen-space gradient after backward (densification reads it); `meta["radii"]` is
    [C,N,2] int32 (0 = culled), `meta["depths"]` [C,N]; with "conics", "visible" and
    "bounds" they make the Projection, and `meta["features"]` [C,N,D'] are the composited
    per-camera features. `fixed` (RGB only) gives the render
    of Gaussians that have not changed since it was made: the tiles only they touch are
    copied from it, which skips their compositing and backward (see FixedLayer).
    `camera_mask` [C,N] bool leaves Gaussian n out of camera c where False (culled there:
    radius 0, no gradient), so one render can show each camera its own rows.
    `backend` picks projection, binning and compositing: "auto" (the Triton kernels on CUDA
    where triton imports, the native kernels on CPU where they build, else torch), "torch",
    "native" or "triton" (see `select_backend`); None takes the process default
    (`use_backend`, "auto" unless set). `meta["backend"]` names the one used.
    `rasterize_mode` "classic" adds `eps2d` to each screen covariance as 3DGS does (a
    sub-pixel Gaussian grows and brightens); "antialiased" also scales its opacity by
    `blur_compensation`, keeping its screen integral (gsplat's mode of that name).
    """
    _check(
        not isinstance(tile_size, bool) and isinstance(tile_size, int) and tile_size >= 1,
        f"tile_size must be an int >= 1, got {tile_size!r}",
    )
    _check(
        rasterize_mode in RASTERIZE_MODES,
        f"rasterize_mode must be one of {RASTERIZE_MODES}, got {rasterize_mode!r}",
    )
    if fixed is not None:
        channels = 3 if sh_degree is not None else colors.shape[-1]
        validate_fixed(
            fixed, means.shape[0], viewmats.shape[0], width, height, channels, render_mode
        )
    chosen = select_backend(default_backend() if backend is None else backend, means)
    prep = prepare(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        sh_degree=sh_degree, backgrounds=backgrounds, near_plane=near_plane,
        far_plane=far_plane, eps2d=eps2d, render_mode=render_mode,
        fixed=fixed, project=chosen.project,
    )  # fmt: skip
    proj = _leave_out(prep.proj, camera_mask)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    bins = chosen.bin(proj.bounds, proj.depths.detach(), proj.visible, width, height, tile_size)
    opac = torch.where(proj.visible, opacities[None], torch.zeros_like(proj.depths))
    if rasterize_mode == "antialiased":
        opac = opac * blur_compensation(proj.conics, eps2d)
    render, alphas = chosen.composite.apply(
        means2d, proj.conics, opac, prep.features, prep.backgrounds, proj.bounds,
        _moving_tiles(bins, fixed), width, height, fixed,
    )  # fmt: skip
    render = finish_depth(render, alphas, render_mode)
    meta = {
        "means2d": means2d,
        "radii": proj.radii,
        "depths": proj.depths,
        "conics": proj.conics,
        "visible": proj.visible,
        "width": width,
        "height": height,
        "n_cameras": viewmats.shape[0],
        "tile_size": tile_size,
        "num_pairs": int(bins.pair_gaussian.numel()),
        "bounds": proj.bounds,
        "features": prep.features,
        "backend": chosen.name,
    }
    return render, alphas, meta
