// Native binning: the same per-tile, depth-ordered Gaussian lists as relaygs.splat.tiles,
// by a counting sort instead of two general sorts.
//
// Per camera (in parallel: each camera owns its own range of tiles): stable-sort the visible
// Gaussians by depth, count the tiles each one's pixel box touches, then, after one prefix
// sum over all tiles, walk the Gaussians front to back appending each to its tiles' lists.
// Within a tile the list is in depth order with ties by index, as the torch path's stable
// sorts give, so both paths bin identically.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <numeric>
#include <vector>

#include "kernels.h"

namespace relaygs {
namespace {

struct Grid {
  int64_t tile_size, tiles_x, tiles_y, n;

  int64_t per_camera() const { return tiles_x * tiles_y; }
};

// Visible Gaussians of camera c, nearest first (ties by index).
template <typename scalar_t>
std::vector<int64_t> depth_order(const scalar_t* depths, const bool* visible, int64_t c,
                                 int64_t n) {
  std::vector<int64_t> order;
  for (int64_t i = 0; i < n; ++i) {
    if (visible[c * n + i]) order.push_back(i);
  }
  const scalar_t* d = depths + c * n;
  std::stable_sort(order.begin(), order.end(),
                   [d](int64_t a, int64_t b) { return d[a] < d[b]; });
  return order;
}

// Calls visit(tile) for every tile of camera c that box (x0, x1, y0, y1) touches.
template <typename Visit>
void for_each_tile_of(const int32_t* box, int64_t c, const Grid& grid, const Visit& visit) {
  const int64_t tx0 = box[0] / grid.tile_size, tx1 = box[1] / grid.tile_size;
  const int64_t ty0 = box[2] / grid.tile_size, ty1 = box[3] / grid.tile_size;
  for (int64_t ty = ty0; ty <= ty1; ++ty) {
    for (int64_t tx = tx0; tx <= tx1; ++tx) visit(c * grid.per_camera() + ty * grid.tiles_x + tx);
  }
}

}  // namespace

std::vector<at::Tensor> bin_tiles(const at::Tensor& bounds, const at::Tensor& depths,
                                  const at::Tensor& visible, int64_t width, int64_t height,
                                  int64_t tile_size) {
  TORCH_CHECK(bounds.device().is_cpu() && bounds.scalar_type() == at::kInt &&
                  bounds.is_contiguous() && bounds.dim() == 3 && bounds.size(2) == 4,
              "bounds must be a contiguous CPU [C,N,4] int32 tensor");
  TORCH_CHECK(depths.device().is_cpu() && depths.is_contiguous() &&
                  depths.sizes() == bounds.sizes().slice(0, 2),
              "depths must be a contiguous CPU [C,N] tensor");
  TORCH_CHECK(visible.device().is_cpu() && visible.scalar_type() == at::kBool &&
                  visible.is_contiguous() &&
                  visible.sizes() == depths.sizes(),
              "visible must be a contiguous [C,N] bool tensor");
  TORCH_CHECK(tile_size >= 1 && width >= 1 && height >= 1, "bad image or tile size");
  const int64_t cameras = depths.size(0);
  const Grid grid{tile_size, (width + tile_size - 1) / tile_size,
                  (height + tile_size - 1) / tile_size, depths.size(1)};
  const int64_t num_tiles = cameras * grid.per_camera();
  const int32_t* box = bounds.data_ptr<int32_t>();
  const bool* vis = visible.data_ptr<bool>();
  std::vector<std::vector<int64_t>> orders(cameras);
  at::Tensor tile_count = at::zeros({num_tiles}, at::kLong);
  int64_t* count = tile_count.data_ptr<int64_t>();
  AT_DISPATCH_FLOATING_TYPES(depths.scalar_type(), "bin_tiles", [&] {
    const scalar_t* d = depths.data_ptr<scalar_t>();
    at::parallel_for(0, cameras, 1, [&](int64_t begin, int64_t end) {
      for (int64_t c = begin; c < end; ++c) {
        orders[c] = depth_order(d, vis, c, grid.n);
        for (int64_t i : orders[c]) {
          for_each_tile_of(box + (c * grid.n + i) * 4, c, grid,
                           [&](int64_t tile) { ++count[tile]; });
        }
      }
    });
  });
  at::Tensor tile_start = at::empty({num_tiles}, at::kLong);
  int64_t* start = tile_start.data_ptr<int64_t>();
  std::exclusive_scan(count, count + num_tiles, start, int64_t(0));
  const int64_t pairs = num_tiles ? start[num_tiles - 1] + count[num_tiles - 1] : 0;
  at::Tensor pair_gaussian = at::empty({pairs}, at::kLong);
  int64_t* out = pair_gaussian.data_ptr<int64_t>();
  at::parallel_for(0, cameras, 1, [&](int64_t begin, int64_t end) {
    for (int64_t c = begin; c < end; ++c) {
      const int64_t first = c * grid.per_camera();
      std::vector<int64_t> cursor(start + first, start + first + grid.per_camera());
      for (int64_t i : orders[c]) {
        for_each_tile_of(box + (c * grid.n + i) * 4, c, grid,
                         [&](int64_t tile) { out[cursor[tile - first]++] = c * grid.n + i; });
      }
    }
  });
  // Tiles to composite, longest list first (ties by id): the order workers take them in.
  std::vector<int64_t> busy;
  for (int64_t t = 0; t < num_tiles; ++t) {
    if (count[t] > 0) busy.push_back(t);
  }
  std::stable_sort(busy.begin(), busy.end(),
                   [count](int64_t a, int64_t b) { return count[a] > count[b]; });
  at::Tensor order = at::empty({static_cast<int64_t>(busy.size())}, at::kLong);
  std::copy(busy.begin(), busy.end(), order.data_ptr<int64_t>());
  return {pair_gaussian, tile_start, tile_count, order};
}

}  // namespace relaygs
