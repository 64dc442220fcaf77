"""EWA projection of 3D Gaussians to screen-space 2D Gaussians (autograd torch).

Numerics follow gsplat and the reference 3DGS rasteriser: near/far cull, a Jacobian
evaluated at x/z clamped to the frustum widened by 0.3·tan(fov), a 0.3 px² blur on
the covariance diagonal, a det > 0 cull, and per-axis radii. Every division and
square root is fed a value made safe with `where` first, so culled Gaussians get
exactly zero gradient and never produce NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

ALPHA_MIN = 1.0 / 255.0
MAX_SIGMA_MULT = 3.33
FRUSTUM_MARGIN = 0.3
# Scales above this are clamped (zero gradient): keeps J·Σ·Jᵀ finite in float32.
MAX_SCALE = 1e12
# Centres with |x/z| or |y/z| above this are culled before the division (no float32 overflow).
MAX_RATIO = 1e30
# 2D variances (px²) above this are culled: keeps det and its square root finite in float32.
MAX_VAR_PX = 1e14
MAX_FOCAL = 1e20
"""Largest focal length (px) a camera may have: the Jacobian's backward takes fx/depth², which
stays a finite float32 down to the smallest near plane (rasterize.MIN_NEAR_PLANE, 1e-9)."""


@dataclass
class Projection:
    """Per-camera screen-space Gaussians; tensors are [C, N, ...]."""

    means2d: torch.Tensor  # [C,N,2] pixel coordinates (pixel j covers [j, j+1))
    conics: (
        torch.Tensor
    )  # [C,N,3] inverse 2D covariance (A, B, C): power = ½A dx² + B dx dy + ½C dy²
    depths: torch.Tensor  # [C,N] camera-space z
    radii: torch.Tensor  # [C,N,2] int32 per-axis pixel radius, 0 where culled
    visible: torch.Tensor  # [C,N] bool
    bounds: torch.Tensor  # [C,N,4] int32 inclusive pixel box (x0, x1, y0, y1) inside the image


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N,3,3] from wxyz quaternions of any norm.

    The quaternion is first divided by its largest component (no overflow for huge
    values, no underflow for tiny ones). One whose largest component is below the square
    root of the dtype's smallest normal number (about 1e-19 in float32; zero included) maps
    to the identity with zero gradient: the gradient of the division grows as 1/peak², which
    would overflow there.
    """
    peak = quats.abs().amax(dim=-1, keepdim=True)
    degenerate = peak < torch.finfo(quats.dtype).tiny ** 0.5
    scaled = quats / torch.where(degenerate, torch.ones_like(peak), peak)
    norm = torch.linalg.vector_norm(scaled, dim=-1, keepdim=True)
    identity = torch.zeros_like(quats)
    identity[..., 0] = 1.0
    unit = torch.where(degenerate, identity, scaled / torch.where(degenerate, 1.0, norm))
    w, x, y, z = unit.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*quats.shape[:-1], 3, 3)


def covariance_factor(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """R·S [N,3,3] from quaternions and activated scales: the world-space covariance is its
    product with its transpose, which the projection never forms (a thin Gaussian's
    covariance loses its thin axis in float32)."""
    return quat_to_rotmat(quats) * scales.clamp(max=MAX_SCALE).unsqueeze(-2)


def opacity_sigma_multiplier(opacities: torch.Tensor) -> torch.Tensor:
    """How many σ from the centre alpha = o·exp(−power) stays >= 1/255, capped at 3.33.

    With this multiplier the pixel box holds every pixel that can contribute, so the box
    only accelerates and never changes the image. Zero where o < 1/255.
    """
    ratio = torch.clamp_min(opacities / ALPHA_MIN, 1.0)
    return torch.sqrt(2.0 * torch.log(ratio)).clamp(max=MAX_SIGMA_MULT)


def project_gaussians(
    means: torch.Tensor,
    factors: torch.Tensor,
    opacities: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
) -> Projection:
    """Project N Gaussians, covariances given as `factors` [N,3,3] (`covariance_factor`),
    into C cameras (OpenCV axes, world→camera viewmats)."""
    rot = viewmats[:, :3, :3]
    trans = viewmats[:, :3, 3]
    p_cam = torch.einsum("cij,nj->cni", rot, means) + trans[:, None, :]
    x, y, z = p_cam.unbind(-1)
    in_depth = (z >= near_plane) & (z <= far_plane)
    z_safe = torch.where(in_depth, z, torch.ones_like(z))

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    # a centre whose x/z or y/z would overflow is far outside every image: culled, and its
    # offsets zeroed first, since the division's backward would take 0·inf (NaN) for it
    ratio_finite = (x.abs() < z_safe * MAX_RATIO) & (y.abs() < z_safe * MAX_RATIO)
    zero = torch.zeros_like(z)
    ratio_x = torch.where(ratio_finite, x, zero) / z_safe
    ratio_y = torch.where(ratio_finite, y, zero) / z_safe
    u = ratio_x.clamp(
        -(cx / fx + FRUSTUM_MARGIN * tan_fovx), (width - cx) / fx + FRUSTUM_MARGIN * tan_fovx
    )
    v = ratio_y.clamp(
        -(cy / fy + FRUSTUM_MARGIN * tan_fovy), (height - cy) / fy + FRUSTUM_MARGIN * tan_fovy
    )
    jac = torch.stack(
        [fx / z_safe, zero, -fx * u / z_safe, zero, fy / z_safe, -fy * v / z_safe], dim=-1
    ).reshape(*z.shape, 2, 3)
    # the 2D covariance is M·Mᵀ with rows m0, m1 of M = J·W·R·S [C,N,2,3]
    m0, m1 = (jac @ rot[:, None] @ factors[None]).unbind(-2)
    a0, b, c0 = (m0 * m0).sum(-1), (m0 * m1).sum(-1), (m1 * m1).sum(-1)
    a, c = a0 + eps2d, c0 + eps2d
    bounded = in_depth & ratio_finite & (a < MAX_VAR_PX) & (c < MAX_VAR_PX) & (b.abs() < MAX_VAR_PX)
    a_s = torch.where(bounded, a, torch.ones_like(a))
    b_s = torch.where(bounded, b, torch.zeros_like(b))
    c_s = torch.where(bounded, c, torch.ones_like(c))
    m0_s = torch.where(bounded[..., None], m0, torch.zeros_like(m0))
    m1_s = torch.where(bounded[..., None], m1, torch.zeros_like(m1))
    # det = a·c − b² as |m0 × m1|² + eps2d·(a0 + c0) + eps2d² (Lagrange's identity): no
    # cancellation between a·c and b², which culls or misshapes long thin Gaussians in float32
    thin = torch.linalg.cross(m0_s, m1_s).square().sum(-1)
    det = thin + eps2d * (a_s + c_s) - eps2d * eps2d
    # the backward of x/det takes det², which must not underflow
    ok = bounded & (det > torch.finfo(det.dtype).tiny ** 0.5)
    det_s = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c_s / det_s, -b_s / det_s, a_s / det_s], dim=-1)

    # x/z first: fx·x may overflow where x/z does not, and the division's backward would
    # then multiply a culled row's zero gradient by inf (NaN); fx·(x/z) = inf is culled below
    mx = fx * ratio_x + cx
    my = fy * ratio_y + cy
    mult = opacity_sigma_multiplier(opacities.detach())[None].expand_as(a)
    with torch.no_grad():
        rx = torch.ceil(mult * torch.sqrt(a_s))
        ry = torch.ceil(mult * torch.sqrt(c_s))
        ok = ok & (mult > 0) & torch.isfinite(mx) & torch.isfinite(my)
        mx_s = torch.where(ok, mx, zero).detach()
        my_s = torch.where(ok, my, zero).detach()
        # Pixel j is inside when |j + 0.5 − m| <= r.
        x0 = torch.ceil(mx_s - rx - 0.5).clamp(min=0)
        x1 = torch.floor(mx_s + rx - 0.5).clamp(max=width - 1)
        y0 = torch.ceil(my_s - ry - 0.5).clamp(min=0)
        y1 = torch.floor(my_s + ry - 0.5).clamp(max=height - 1)
        visible = ok & (x0 <= x1) & (y0 <= y1)
        bounds = torch.stack([x0, x1, y0, y1], dim=-1).clamp(-1, 2**30)
        bounds = torch.where(visible[..., None], bounds, torch.zeros_like(bounds)).to(torch.int32)
        radii = torch.stack([rx, ry], dim=-1).clamp(max=2**30)
        radii = torch.where(visible[..., None], radii, torch.zeros_like(radii)).to(torch.int32)

    vis = visible[..., None]
    means2d = torch.where(vis, torch.stack([mx, my], dim=-1), torch.zeros_like(p_cam[..., :2]))
    conics = torch.where(vis, conics, torch.zeros_like(conics))
    depths = torch.where(visible, z, zero)
    return Projection(means2d, conics, depths, radii, visible, bounds)
