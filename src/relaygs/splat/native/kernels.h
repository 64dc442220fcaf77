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

// EWA projection into C cameras: {means2d, conics, depths, radii, visible, bounds}.
std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& factors,
                                        const at::Tensor& opacities, const at::Tensor& viewmats,
                                        const at::Tensor& ks, int64_t width, int64_t height,
                                        double near_plane, double far_plane, double eps2d);

// Gradients {[N,3], [N,3,3]} of the means and covariance factors from the projection's.
std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& factors,
                                         const at::Tensor& opacities,
                                         const at::Tensor& viewmats, const at::Tensor& ks,
                                         int64_t width, int64_t height, double near_plane,
                                         double far_plane, double eps2d,
                                         const at::Tensor& grad_means2d,
                                         const at::Tensor& grad_conics,
                                         const at::Tensor& grad_depths);

// HexPlane features [N, C*levels] at normalised coords [N,3] and grid times [N] from
// channel-last planes (per level: spatial [3,R,R,C], time [3,T,R,C]).
at::Tensor hexplane_forward(const at::Tensor& coords, const at::Tensor& times,
                            const std::vector<at::Tensor>& spatial,
                            const std::vector<at::Tensor>& time);

// Gradients {per level: spatial [3,C,R,R], time [3,C,T,R] (channel-first)..., coords [N,3]}.
std::vector<at::Tensor> hexplane_backward(const at::Tensor& coords, const at::Tensor& times,
                                          const std::vector<at::Tensor>& spatial,
                                          const std::vector<at::Tensor>& time,
                                          const at::Tensor& grad_features);

// {sum over planes of the mean squared second difference along H (`rows`) plus along W
// (`columns`) (0-dim), its gradient [P,C,H,W]} of planes [P,C,H,W].
std::vector<at::Tensor> second_difference(const at::Tensor& planes, bool rows, bool columns);

// {mean SSIM (0-dim), the five blurred maps [5, B*H*W*C]} of channel-last batches x, y.
std::vector<at::Tensor> ssim_forward(const at::Tensor& x, const at::Tensor& y);

// dL/dx of L = grad · ssim(x, y), from the forward's blurred maps.
at::Tensor ssim_backward(const at::Tensor& x, const at::Tensor& y, const at::Tensor& blurred,
                         const at::Tensor& grad);

// For each of queries [Q,3] the index (int64 [Q]) of its nearest of points [P,3] (P >= 1),
// the first one among equally near points.
at::Tensor nearest_points(const at::Tensor& queries, const at::Tensor& points);

}  // namespace relaygs
