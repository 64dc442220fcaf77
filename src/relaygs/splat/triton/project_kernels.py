"""Triton kernels projecting 3D Gaussians into C cameras, forward and backward.

One program per block of Gaussians, every camera in it in camera order: the backward sums a
Gaussian's gradient over the cameras inside its program, so it needs no atomics and its
result does not depend on the launch. Forward and backward evaluate each (camera, Gaussian)
pair with the same function, so they agree on which pairs are visible. The numerics are those
of relaygs.splat.projection and the native kernel (near/far cull, the Jacobian at x/z clamped
to the widened frustum, the eps2d blur, det from Lagrange's identity, the variance and det
culls, opacity-aware pixel boxes); every division is fed a value made safe first and every
gradient of a culled pair is selected away, so no NaN or inf reaches a gradient.

`settings` is a [4] tensor of the inputs' dtype: near plane, far plane, eps2d and the smallest
det kept (√ of the dtype's smallest normal), so that float64 keeps its own constants.
"""

from __future__ import annotations

import triton
import triton.language as tl

ALPHA_MIN = tl.constexpr(1.0 / 255.0)
MAX_SIGMA_MULT = tl.constexpr(3.33)
FRUSTUM_MARGIN = tl.constexpr(0.3)
MAX_RATIO = tl.constexpr(1e30)
MAX_VAR_PX = tl.constexpr(1e14)
MAX_PIXEL = tl.constexpr(1073741824.0)  # 2^30: boxes and radii are clamped to it


@triton.jit
def _sqrt(x):
    """The correctly rounded square root (tl.sqrt is the fast one in float32; float64's is
    already correctly rounded)."""
    return tl.sqrt(x) if x.dtype == tl.float64 else tl.sqrt_rn(x)


@triton.jit
def _camera(viewmats, ks, c, width, height):
    """Camera c: rotation rows, translation, intrinsics and the clamp range of x/z, y/z."""
    v = viewmats + c * 16
    k = ks + c * 9
    r00, r01, r02, t0 = tl.load(v + 0), tl.load(v + 1), tl.load(v + 2), tl.load(v + 3)
    r10, r11, r12, t1 = tl.load(v + 4), tl.load(v + 5), tl.load(v + 6), tl.load(v + 7)
    r20, r21, r22, t2 = tl.load(v + 8), tl.load(v + 9), tl.load(v + 10), tl.load(v + 11)
    fx, cx, fy, cy = tl.load(k + 0), tl.load(k + 2), tl.load(k + 4), tl.load(k + 5)
    # sizes promoted by arithmetic: Triton passes an int argument equal to 1 as a constant
    w = fx * 0.0 + width
    h = fx * 0.0 + height
    tan_x = 0.5 * w / fx
    tan_y = 0.5 * h / fy
    u_lo = -(cx / fx + FRUSTUM_MARGIN * tan_x)
    u_hi = (w - cx) / fx + FRUSTUM_MARGIN * tan_x
    v_lo = -(cy / fy + FRUSTUM_MARGIN * tan_y)
    v_hi = (h - cy) / fy + FRUSTUM_MARGIN * tan_y
    rot = (r00, r01, r02, r10, r11, r12, r20, r21, r22)
    return rot, t0, t1, t2, fx, fy, cx, cy, u_lo, u_hi, v_lo, v_hi


@triton.jit
def _gaussians(means, factors, opacities, rows, valid):
    """Centres, factor F = R·S (row-major) and opacity of the Gaussians at `rows`."""
    px = tl.load(means + rows * 3 + 0, mask=valid, other=0.0)
    py = tl.load(means + rows * 3 + 1, mask=valid, other=0.0)
    pz = tl.load(means + rows * 3 + 2, mask=valid, other=0.0)
    f = factors + rows * 9
    f00 = tl.load(f + 0, mask=valid, other=0.0)
    f01 = tl.load(f + 1, mask=valid, other=0.0)
    f02 = tl.load(f + 2, mask=valid, other=0.0)
    f10 = tl.load(f + 3, mask=valid, other=0.0)
    f11 = tl.load(f + 4, mask=valid, other=0.0)
    f12 = tl.load(f + 5, mask=valid, other=0.0)
    f20 = tl.load(f + 6, mask=valid, other=0.0)
    f21 = tl.load(f + 7, mask=valid, other=0.0)
    f22 = tl.load(f + 8, mask=valid, other=0.0)
    opacity = tl.load(opacities + rows, mask=valid, other=0.0)
    # how many σ from the centre alpha stays >= 1/255 (projection.opacity_sigma_multiplier)
    ratio = tl.maximum(opacity / ALPHA_MIN, 1.0)
    mult = tl.minimum(_sqrt(2.0 * tl.log(ratio)), MAX_SIGMA_MULT)
    fac = (f00, f01, f02, f10, f11, f12, f20, f21, f22)
    return px, py, pz, fac, mult


@triton.jit
def _project_pair(viewmats, ks, cam, settings, width, height, px, py, pz, fac, mult):
    """Camera `cam`'s view of a block of Gaussians: every intermediate the backward needs
    (the camera's rotation and focal lengths among them), whether each pair is visible, and
    its per-axis radius and inclusive pixel box."""
    rot, t0, t1, t2, fx, fy, cx, cy, u_lo, u_hi, v_lo, v_hi = _camera(
        viewmats, ks, cam, width, height
    )
    near, far = tl.load(settings + 0), tl.load(settings + 1)
    eps, det_min = tl.load(settings + 2), tl.load(settings + 3)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = fac
    x = r00 * px + r01 * py + r02 * pz + t0
    y = r10 * px + r11 * py + r12 * pz + t1
    z = r20 * px + r21 * py + r22 * pz + t2
    in_depth = (z >= near) & (z <= far)
    z = tl.where(in_depth, z, 1.0)
    ratio_ok = in_depth & (tl.abs(x) < z * MAX_RATIO) & (tl.abs(y) < z * MAX_RATIO)
    x = tl.where(ratio_ok, x, 0.0)
    y = tl.where(ratio_ok, y, 0.0)
    rx = x / z
    ry = y / z
    u_free = (rx >= u_lo) & (rx <= u_hi)
    v_free = (ry >= v_lo) & (ry <= v_hi)
    u = tl.minimum(tl.maximum(rx, u_lo), u_hi)
    v = tl.minimum(tl.maximum(ry, v_lo), v_hi)
    j00 = fx / z
    j02 = -fx * u / z
    j11 = fy / z
    j12 = -fy * v / z
    jr00 = j00 * r00 + j02 * r20
    jr01 = j00 * r01 + j02 * r21
    jr02 = j00 * r02 + j02 * r22
    jr10 = j11 * r10 + j12 * r20
    jr11 = j11 * r11 + j12 * r21
    jr12 = j11 * r12 + j12 * r22
    m00 = jr00 * f00 + jr01 * f10 + jr02 * f20
    m01 = jr00 * f01 + jr01 * f11 + jr02 * f21
    m02 = jr00 * f02 + jr01 * f12 + jr02 * f22
    m10 = jr10 * f00 + jr11 * f10 + jr12 * f20
    m11 = jr10 * f01 + jr11 * f11 + jr12 * f21
    m12 = jr10 * f02 + jr11 * f12 + jr12 * f22
    a = m00 * m00 + m01 * m01 + m02 * m02 + eps
    b = m00 * m10 + m01 * m11 + m02 * m12
    c = m10 * m10 + m11 * m11 + m12 * m12 + eps
    bounded = ratio_ok & (a < MAX_VAR_PX) & (c < MAX_VAR_PX) & (tl.abs(b) < MAX_VAR_PX)
    a = tl.where(bounded, a, 1.0)
    b = tl.where(bounded, b, 0.0)
    c = tl.where(bounded, c, 1.0)
    w0 = m01 * m12 - m02 * m11
    w1 = m02 * m10 - m00 * m12
    w2 = m00 * m11 - m01 * m10
    det = tl.where(bounded, w0 * w0 + w1 * w1 + w2 * w2, 0.0) + eps * (a + c) - eps * eps
    ok = bounded & (det > det_min)
    det = tl.where(ok, det, 1.0)
    mx = fx * rx + cx
    my = fy * ry + cy
    finite = ((mx - mx) == 0.0) & ((my - my) == 0.0)
    ok = ok & (mult > 0.0) & finite
    mx = tl.where(ok, mx, 0.0)
    my = tl.where(ok, my, 0.0)
    radius_x = tl.ceil(mult * _sqrt(a))
    radius_y = tl.ceil(mult * _sqrt(c))
    x0 = tl.maximum(tl.ceil(mx - radius_x - 0.5), 0.0)
    x1 = tl.minimum(tl.floor(mx + radius_x - 0.5), mx * 0.0 + (width - 1))
    y0 = tl.maximum(tl.ceil(my - radius_y - 0.5), 0.0)
    y1 = tl.minimum(tl.floor(my + radius_y - 0.5), my * 0.0 + (height - 1))
    visible = ok & (x0 <= x1) & (y0 <= y1)
    jr = (jr00, jr01, jr02, jr10, jr11, jr12)
    m = (m00, m01, m02, m10, m11, m12)
    geometry = (x, y, z, u, v, u_free, v_free)
    conic = (a, b, c, det)
    pixels = (radius_x, radius_y, x0, x1, y0, y1)
    return (rot, fx, fy), geometry, jr, m, conic, mx, my, visible, pixels


@triton.jit
def _pixel_int(value, visible, low):
    """A radius or box corner as int32: clamped to [low, 2^30], zero where not visible."""
    clamped = tl.minimum(tl.maximum(value, low), MAX_PIXEL)
    return tl.where(visible, clamped, 0.0).to(tl.int32)


@triton.jit
def project_forward_kernel(
    means, factors, opacities, viewmats, ks, settings,
    means2d, conics, depths, radii, visible_out, bounds,
    n, cams, width, height,
    BLOCK: tl.constexpr,
):  # fmt: skip
    """means2d [C,N,2], conics [C,N,3], depths [C,N], radii [C,N,2] int32, visible [C,N]
    (int8) and bounds [C,N,4] int32 of the program's Gaussians in every camera."""
    rows = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    valid = rows < n
    px, py, pz, fac, mult = _gaussians(means, factors, opacities, rows, valid)
    cam = 0
    while cam < cams:  # not range(cams): Triton 3.6's interpreter cannot take it
        _camera_of, geometry, _jr, _m, conic, mx, my, seen, pixels = _project_pair(
            viewmats, ks, cam, settings, width, height, px, py, pz, fac, mult
        )
        _x, _y, z, _u, _v, _u_free, _v_free = geometry
        a, b, c, det = conic
        rad_x, rad_y, x0, x1, y0, y1 = pixels
        out = cam * n + rows
        tl.store(means2d + out * 2 + 0, tl.where(seen, mx, 0.0), mask=valid)
        tl.store(means2d + out * 2 + 1, tl.where(seen, my, 0.0), mask=valid)
        tl.store(conics + out * 3 + 0, tl.where(seen, c / det, 0.0), mask=valid)
        tl.store(conics + out * 3 + 1, tl.where(seen, -b / det, 0.0), mask=valid)
        tl.store(conics + out * 3 + 2, tl.where(seen, a / det, 0.0), mask=valid)
        tl.store(depths + out, tl.where(seen, z, 0.0), mask=valid)
        tl.store(radii + out * 2 + 0, _pixel_int(rad_x, seen, 0.0), mask=valid)
        tl.store(radii + out * 2 + 1, _pixel_int(rad_y, seen, 0.0), mask=valid)
        tl.store(visible_out + out, seen.to(tl.int8), mask=valid)
        tl.store(bounds + out * 4 + 0, _pixel_int(x0, seen, -1.0), mask=valid)
        tl.store(bounds + out * 4 + 1, _pixel_int(x1, seen, -1.0), mask=valid)
        tl.store(bounds + out * 4 + 2, _pixel_int(y0, seen, -1.0), mask=valid)
        tl.store(bounds + out * 4 + 3, _pixel_int(y1, seen, -1.0), mask=valid)
        cam += 1


@triton.jit
def project_backward_kernel(
    means, factors, opacities, viewmats, ks, settings,
    grad_means2d, grad_conics, grad_depths, grad_means, grad_factors,
    n, cams, width, height,
    BLOCK: tl.constexpr,
):  # fmt: skip
    """grad_means [N,3] and grad_factors [N,3,3]: each visible pair's gradient of its
    means2d, conic and depth, summed over the cameras in camera order."""
    rows = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    valid = rows < n
    eps = tl.load(settings + 2)
    px, py, pz, fac, mult = _gaussians(means, factors, opacities, rows, valid)
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = fac
    zero = tl.zeros([BLOCK], means.dtype.element_ty)
    gmx = zero
    gmy = zero
    gmz = zero
    g00 = zero
    g01 = zero
    g02 = zero
    g10 = zero
    g11 = zero
    g12 = zero
    g20 = zero
    g21 = zero
    g22 = zero
    cam = 0
    while cam < cams:  # not range(cams): Triton 3.6's interpreter cannot take it
        camera, geometry, jr, m, conic, _mx, _my, seen, _pixels = _project_pair(
            viewmats, ks, cam, settings, width, height, px, py, pz, fac, mult
        )
        rot, fx, fy = camera
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
        x, y, z, u, v, u_free, v_free = geometry
        a, b, c, det = conic
        jr00, jr01, jr02, jr10, jr11, jr12 = jr
        m00, m01, m02, m10, m11, m12 = m
        take = seen & valid
        out = cam * n + rows
        g2x = tl.where(take, tl.load(grad_means2d + out * 2 + 0, mask=take, other=0.0), 0.0)
        g2y = tl.where(take, tl.load(grad_means2d + out * 2 + 1, mask=take, other=0.0), 0.0)
        gc0 = tl.where(take, tl.load(grad_conics + out * 3 + 0, mask=take, other=0.0), 0.0)
        gc1 = tl.where(take, tl.load(grad_conics + out * 3 + 1, mask=take, other=0.0), 0.0)
        gc2 = tl.where(take, tl.load(grad_conics + out * 3 + 2, mask=take, other=0.0), 0.0)
        gdepth = tl.where(take, tl.load(grad_depths + out, mask=take, other=0.0), 0.0)
        # conics = (c, −b, a) / det
        gdet = -(gc0 * c - gc1 * b + gc2 * a) / (det * det)
        ga = gc2 / det + eps * gdet
        gb = -gc1 / det
        gc = gc0 / det + eps * gdet
        # a = m0·m0 + eps, b = m0·m1, c = m1·m1 + eps, det = |m0 × m1|² + eps·(a + c) − eps²
        gw0 = 2.0 * gdet * (m01 * m12 - m02 * m11)
        gw1 = 2.0 * gdet * (m02 * m10 - m00 * m12)
        gw2 = 2.0 * gdet * (m00 * m11 - m01 * m10)
        gm00 = 2.0 * ga * m00 + gb * m10 + (m11 * gw2 - m12 * gw1)
        gm01 = 2.0 * ga * m01 + gb * m11 + (m12 * gw0 - m10 * gw2)
        gm02 = 2.0 * ga * m02 + gb * m12 + (m10 * gw1 - m11 * gw0)
        gm10 = 2.0 * gc * m10 + gb * m00 + (gw1 * m02 - gw2 * m01)
        gm11 = 2.0 * gc * m11 + gb * m01 + (gw2 * m00 - gw0 * m02)
        gm12 = 2.0 * gc * m12 + gb * m02 + (gw0 * m01 - gw1 * m00)
        # M = (J·R)·F
        g00 += tl.where(take, jr00 * gm00 + jr10 * gm10, 0.0)
        g01 += tl.where(take, jr00 * gm01 + jr10 * gm11, 0.0)
        g02 += tl.where(take, jr00 * gm02 + jr10 * gm12, 0.0)
        g10 += tl.where(take, jr01 * gm00 + jr11 * gm10, 0.0)
        g11 += tl.where(take, jr01 * gm01 + jr11 * gm11, 0.0)
        g12 += tl.where(take, jr01 * gm02 + jr11 * gm12, 0.0)
        g20 += tl.where(take, jr02 * gm00 + jr12 * gm10, 0.0)
        g21 += tl.where(take, jr02 * gm01 + jr12 * gm11, 0.0)
        g22 += tl.where(take, jr02 * gm02 + jr12 * gm12, 0.0)
        gjr00 = gm00 * f00 + gm01 * f01 + gm02 * f02
        gjr01 = gm00 * f10 + gm01 * f11 + gm02 * f12
        gjr02 = gm00 * f20 + gm01 * f21 + gm02 * f22
        gjr10 = gm10 * f00 + gm11 * f01 + gm12 * f02
        gjr11 = gm10 * f10 + gm11 * f11 + gm12 * f12
        gjr12 = gm10 * f20 + gm11 * f21 + gm12 * f22
        # J·R with J = (fx/z, 0, −fx·u/z; 0, fy/z, −fy·v/z)
        gj00 = gjr00 * r00 + gjr01 * r01 + gjr02 * r02
        gj02 = gjr00 * r20 + gjr01 * r21 + gjr02 * r22
        gj11 = gjr10 * r10 + gjr11 * r11 + gjr12 * r12
        gj12 = gjr10 * r20 + gjr11 * r21 + gjr12 * r22
        z2 = z * z
        gz = gdepth - gj00 * fx / z2 + gj02 * fx * u / z2 - gj11 * fy / z2 + gj12 * fy * v / z2
        grx = g2x * fx + tl.where(u_free, -gj02 / z * fx, 0.0)
        gry = g2y * fy + tl.where(v_free, -gj12 / z * fy, 0.0)
        # rx = x/z, ry = y/z; (x, y, z) = R·mean + t
        gx = grx / z
        gy = gry / z
        gz = gz - grx * x / z2 - gry * y / z2
        gmx += tl.where(take, r00 * gx + r10 * gy + r20 * gz, 0.0)
        gmy += tl.where(take, r01 * gx + r11 * gy + r21 * gz, 0.0)
        gmz += tl.where(take, r02 * gx + r12 * gy + r22 * gz, 0.0)
        cam += 1
    tl.store(grad_means + rows * 3 + 0, gmx, mask=valid)
    tl.store(grad_means + rows * 3 + 1, gmy, mask=valid)
    tl.store(grad_means + rows * 3 + 2, gmz, mask=valid)
    f = grad_factors + rows * 9
    tl.store(f + 0, g00, mask=valid)
    tl.store(f + 1, g01, mask=valid)
    tl.store(f + 2, g02, mask=valid)
    tl.store(f + 3, g10, mask=valid)
    tl.store(f + 4, g11, mask=valid)
    tl.store(f + 5, g12, mask=valid)
    tl.store(f + 6, g20, mask=valid)
    tl.store(f + 7, g21, mask=valid)
    tl.store(f + 8, g22, mask=valid)
