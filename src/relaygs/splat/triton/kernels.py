"""Triton kernels compositing binned screen-space Gaussians, forward and backward.

One program per (tile, block of up to 256 of its pixels); the pixels are the lanes. A program
walks its tile's depth-ordered list in batches of BATCH Gaussians, each batch a dense
[pixels, BATCH] block: transmittance inside a batch is a cumulative product along the batch,
so the early stop needs no sequential loop, and the walk ends once every pixel has stopped.
The forward keeps per pixel only the final transmittance and the index of the last
composited pair; the backward walks back to front from each tile's deepest such pair,
recovering T before each pair from T after it (divided by a reverse cumulative product of
1 − α, each factor >= 0.01), and adds every pair's gradients into its Gaussian's row with
atomics. Numerics are those of relaygs.splat.composite (docs/splatting.md).

Importing this module decorates the kernels: with TRITON_INTERPRET=1 set then, they run on
CPU tensors in Triton's interpreter (the tests), else they compile for the GPU.
"""

from __future__ import annotations

import triton
import triton.language as tl

# Constants the kernels read (Triton takes module globals only as constexpr).
ALPHA_MIN = tl.constexpr(1.0 / 255.0)
ALPHA_MAX = tl.constexpr(0.99)
T_MIN = tl.constexpr(1e-4)
MAX_POWER = tl.constexpr(40.0)
COLUMNS = tl.constexpr(10)  # the packed table of relaygs.splat.composite._pack
GRAD_COLUMNS = tl.constexpr(6)  # mean x, mean y, conic A, B, C, opacity


@triton.jit
def _tile_pixels(
    tiles, tile_start, tile_count, tile_size, tiles_x, tiles_y, width, height, PIXELS: tl.constexpr
):
    """The program's tile: where its list starts and how long it is, its pixels' coordinates
    and flat [C,H,W] index, and which lanes are pixels of the image in a non-empty tile (an
    empty one keeps what the caller put there)."""
    tile = tl.load(tiles + tl.program_id(0))
    start = tl.load(tile_start + tile)
    count = tl.load(tile_count + tile).to(tl.int32)
    lane = tl.program_id(1) * PIXELS + tl.arange(0, PIXELS)
    per_camera = tiles_x * tiles_y
    local = tile % per_camera
    x = (local % tiles_x) * tile_size + lane % tile_size
    y = (local // tiles_x) * tile_size + lane // tile_size
    # count compared per lane: the interpreter broadcasts a scalar bool to int32 lanes
    inside = (lane < tile_size * tile_size) & (x < width) & (y < height) & (lane * 0 < count)
    pixel = ((tile // per_camera) * height + y) * width + x
    return start, count, x, y, inside, pixel


@triton.jit
def _pairs(table, pairs, index, valid, px, py):
    """The Gaussians at list positions `index` evaluated at every pixel: their row ids,
    offsets dx, dy [P,B], exp(−power), raw and clamped alpha, whether each pair is composited
    at all (inside the box, power >= 0, alpha >= 1/255), and their conic A, B, C [B]."""
    gid = tl.load(pairs + index, mask=valid, other=0)
    row = table + gid * COLUMNS
    mx = tl.load(row + 0, mask=valid, other=0.0)
    my = tl.load(row + 1, mask=valid, other=0.0)
    a = tl.load(row + 2, mask=valid, other=0.0)
    b = tl.load(row + 3, mask=valid, other=0.0)
    c = tl.load(row + 4, mask=valid, other=0.0)
    opacity = tl.load(row + 5, mask=valid, other=0.0)
    x0 = tl.load(row + 6, mask=valid, other=0.0)
    x1 = tl.load(row + 7, mask=valid, other=-1.0)
    y0 = tl.load(row + 8, mask=valid, other=0.0)
    y1 = tl.load(row + 9, mask=valid, other=-1.0)
    dx = px[:, None] + 0.5 - mx[None, :]
    dy = py[:, None] + 0.5 - my[None, :]
    power = 0.5 * a[None, :] * dx * dx + b[None, :] * dx * dy + 0.5 * c[None, :] * dy * dy
    in_box = (px[:, None] >= x0[None, :]) & (px[:, None] <= x1[None, :])
    in_box = in_box & (py[:, None] >= y0[None, :]) & (py[:, None] <= y1[None, :])
    gauss = tl.exp(-tl.minimum(tl.maximum(power, 0.0), MAX_POWER))
    alpha_raw = opacity[None, :] * gauss
    alpha = tl.minimum(alpha_raw, ALPHA_MAX)
    composited = in_box & (power >= 0.0) & (alpha >= ALPHA_MIN) & valid[None, :]
    return gid, dx, dy, gauss, alpha_raw, alpha, composited, a, b, c


@triton.jit
def _row_colors(colors, gid, valid, channels, CHANNELS: tl.constexpr):
    """The colour rows [B, CHANNELS] of Gaussians `gid` (zero past `channels`)."""
    ch = tl.arange(0, CHANNELS)
    mask = valid[:, None] & (ch[None, :] < channels)
    return tl.load(colors + gid[:, None] * channels + ch[None, :], mask=mask, other=0.0)


@triton.jit
def _weighted_colors(weight, colors, gid, valid, channels, CHANNELS: tl.constexpr):
    """Per pixel and channel [P, CHANNELS], Σ_b weight[p, b] · colour of Gaussian gid[b], the
    batch as the last axis. Written as sum(w[:, :, None] · c[None], axis=1), Triton's compiler
    turns it into a matrix product once CHANNELS >= 16, whose tensor-core form is wrong for
    batches under 8 and TF32-rounded above (an H200 with Triton 3.6: 32 channels off by 0.9)."""
    ch = tl.arange(0, CHANNELS)
    mask = (ch[:, None] < channels) & valid[None, :]
    columns = tl.load(colors + gid[None, :] * channels + ch[:, None], mask=mask, other=0.0)
    return tl.sum(weight[:, None, :] * columns[None, :, :], axis=2)


@triton.jit
def composite_forward_kernel(
    table,
    colors,
    pairs,
    tile_start,
    tile_count,
    tiles,
    out,
    t_final,
    last,
    tile_size,
    tiles_x,
    tiles_y,
    width,
    height,
    channels,
    PIXELS: tl.constexpr,
    BATCH: tl.constexpr,
    CHANNELS: tl.constexpr,
):
    """Front to back through one tile's list: out [C,H,W,D], t_final [C,H,W] and last
    [C,H,W] (int32, −1 where nothing was composited) at the program's pixels."""
    start, count, x, y, inside, pixel = _tile_pixels(
        tiles, tile_start, tile_count, tile_size, tiles_x, tiles_y, width, height, PIXELS
    )
    dtype = table.dtype.element_ty
    px = x.to(dtype)
    py = y.to(dtype)
    steps = tl.arange(0, BATCH)
    trans = tl.full([PIXELS], 1.0, dtype)
    last_hit = tl.full([PIXELS], -1, tl.int32)
    acc = tl.zeros([PIXELS, CHANNELS], dtype)
    alive = inside
    first = 0
    busy = tl.max(alive.to(tl.int32), axis=0)
    while (first < count) & (busy > 0):
        index = first + steps
        valid = index < count
        gid, _dx, _dy, _gauss, _alpha_raw, alpha, composited, _a, _b, _c = _pairs(
            table, pairs, start + index, valid, px, py
        )
        hit = composited & alive[:, None]
        # T after each pair if every hit pair so far is taken; it only falls along the batch,
        # so the pairs kept by the early stop (T after >= 1e-4) are a prefix of the hits.
        after = trans[:, None] * tl.cumprod(tl.where(hit, 1.0 - alpha, 1.0), axis=1)
        take = hit & (after >= T_MIN)
        weight = tl.where(take, alpha * after / (1.0 - alpha), 0.0)
        trans = tl.min(tl.where(take, after, trans[:, None]), axis=1)
        last_hit = tl.maximum(last_hit, tl.max(tl.where(take, index[None, :], -1), axis=1))
        stopped = tl.max((hit & (after < T_MIN)).to(tl.int32), axis=1)
        alive = alive & (stopped == 0)
        acc += _weighted_colors(weight, colors, gid, valid, channels, CHANNELS)
        first += BATCH
        busy = tl.max(alive.to(tl.int32), axis=0)
    ch = tl.arange(0, CHANNELS)
    tl.store(t_final + pixel, trans, mask=inside)
    tl.store(last + pixel, last_hit, mask=inside)
    out_mask = inside[:, None] & (ch[None, :] < channels)
    tl.store(out + pixel[:, None] * channels + ch[None, :], acc, mask=out_mask)


@triton.jit
def composite_backward_kernel(
    table,
    colors,
    pairs,
    tile_start,
    tile_count,
    tiles,
    grad_out,
    pixel_k,
    t_final,
    last,
    grad_table,
    grad_colors,
    tile_size,
    tiles_x,
    tiles_y,
    width,
    height,
    channels,
    PIXELS: tl.constexpr,
    BATCH: tl.constexpr,
    CHANNELS: tl.constexpr,
):
    """Back to front through one tile's list from its deepest composited pair: adds each
    pair's gradients (mean x/y, conic A/B/C, opacity; colour) into its Gaussian's rows."""
    start, _count, x, y, inside, pixel = _tile_pixels(
        tiles, tile_start, tile_count, tile_size, tiles_x, tiles_y, width, height, PIXELS
    )
    dtype = table.dtype.element_ty
    px = x.to(dtype)
    py = y.to(dtype)
    ch = tl.arange(0, CHANNELS)
    ch_ok = ch[None, :] < channels
    grad = tl.load(
        grad_out + pixel[:, None] * channels + ch[None, :], mask=inside[:, None] & ch_ok, other=0.0
    )
    k = tl.load(pixel_k + pixel, mask=inside, other=0.0)
    trans = tl.load(t_final + pixel, mask=inside, other=1.0)
    last_hit = tl.load(last + pixel, mask=inside, other=-1)
    suffix = tl.zeros([PIXELS], dtype)  # Σ over later pairs of v·w
    steps = tl.arange(0, BATCH)
    # one past the current batch's last position; a while loop, since Triton 3.6's
    # interpreter cannot take a range bound from a reduction
    end = tl.max(last_hit, axis=0) + 1
    while end > 0:
        index = end - BATCH + steps
        valid = index >= 0
        gid, dx, dy, gauss, alpha_raw, alpha, composited, a, b, c = _pairs(
            table, pairs, start + index, valid, px, py
        )
        hit = composited & (index[None, :] <= last_hit[:, None])
        one_minus = tl.where(hit, 1.0 - alpha, 1.0)
        before = trans[:, None] / tl.cumprod(one_minus, axis=1, reverse=True)
        weight = tl.where(hit, alpha * before, 0.0)
        color = _row_colors(colors, gid, valid, channels, CHANNELS)
        v = tl.sum(grad[:, None, :] * color[None, :, :], axis=2)  # g·c per pair
        vw = v * weight
        later = suffix[:, None] + tl.cumsum(vw, axis=1, reverse=True) - vw
        # dL/dα = v·T − (Σ_{j>i} v_j w_j + K) / (1 − α); the clamp at 0.99 passes none.
        d_alpha = tl.where(
            hit & (alpha_raw < ALPHA_MAX), v * before - (later + k[:, None]) / one_minus, 0.0
        )
        d_power = -d_alpha * alpha_raw
        s_x = tl.sum(d_power * dx, axis=0)
        s_y = tl.sum(d_power * dy, axis=0)
        row = grad_table + gid * GRAD_COLUMNS
        tl.atomic_add(row + 0, -(a * s_x + b * s_y), mask=valid)
        tl.atomic_add(row + 1, -(b * s_x + c * s_y), mask=valid)
        tl.atomic_add(row + 2, 0.5 * tl.sum(d_power * dx * dx, axis=0), mask=valid)
        tl.atomic_add(row + 3, tl.sum(d_power * dx * dy, axis=0), mask=valid)
        tl.atomic_add(row + 4, 0.5 * tl.sum(d_power * dy * dy, axis=0), mask=valid)
        tl.atomic_add(row + 5, tl.sum(d_alpha * gauss, axis=0), mask=valid)
        d_color = tl.sum(weight[:, :, None] * grad[:, None, :], axis=0)
        tl.atomic_add(
            grad_colors + gid[:, None] * channels + ch[None, :],
            d_color,
            mask=valid[:, None] & ch_ok,
        )
        suffix += tl.sum(vw, axis=1)
        trans = tl.sum(tl.where(steps[None, :] == 0, before, 0.0), axis=1)
        end -= BATCH


INTERPRETED: bool = not isinstance(composite_forward_kernel, triton.runtime.JITFunction)
"""Whether the kernels were decorated for Triton's interpreter (CPU tensors) or the GPU."""
