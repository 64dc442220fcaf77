// The native kernels' entry points, bound to Python in module.cpp.
#pragma once

#include <ATen/ATen.h>

#include <vector>

namespace relaygs {

// Per-tile depth-ordered lists: {pair_gaussian, tile_start, tile_count, busy tiles}.
std::vector<at::Tensor> bin_tiles(const at::Tensor& bounds, const at::Tensor& depths,
                                  const at::Tensor& visible, int64_t width, int64_t height,
                                  int64_t tile_size);

// Composites `tiles` into out [C,H,W,D], t_final [C,H,W] and last [C,H,W] (int32).
void composite_forward(const at::Tensor& table, const at::Tensor& colors,
                       const at::Tensor& pair_gaussian, const at::Tensor& tile_start,
                       const at::Tensor& tile_count, const at::Tensor& tiles, int64_t tile_size,
                       int64_t tiles_x, int64_t tiles_y, int64_t width, int64_t height,
                       at::Tensor out, at::Tensor t_final, at::Tensor last);

// Per-Gaussian gradients {[G,6], [G,D]} of the composited tiles.
std::vector<at::Tensor> composite_backward(
    const at::Tensor& table, const at::Tensor& colors, const at::Tensor& pair_gaussian,
    const at::Tensor& tile_start, const at::Tensor& tile_count, const at::Tensor& tiles,
    int64_t tile_size, int64_t tiles_x, int64_t tiles_y, int64_t width, int64_t height,
    const at::Tensor& grad_out, const at::Tensor& pixel_k, const at::Tensor& t_final,
    const at::Tensor& last);

}  // namespace relaygs
