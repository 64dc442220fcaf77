// Native HexPlane sampling (relaygs.field.hexplane), forward and backward.
//
// Per point and level: six bilinear samples (corner-aligned, border-clamped, as grid_sample
// with align_corners=True and padding_mode="border") of the xy, xz, yz planes and the xt,
// yt, zt planes, multiplied channel by channel. The planes arrive channel-last ([3, H, W, C])
// so one corner's channels are one contiguous run that the compiler vectorises. The backward
// recomputes the samples, takes the products of the other five planes from prefix and
// suffix products (no division), and scatters into one channel-last gradient buffer per
// thread over a fixed split of the points; the buffers are then summed in thread order and
// written back channel-first. Results are therefore deterministic for a given thread count.
// The time coordinate gets no gradient (frame times are not learned). Channel loops are
// `omp simd` (one point's channels in SIMD lanes; the coordinate gradient is kept per channel
// and summed once per point, since a running scalar sum would be one serial chain), and the
// default channel count is compiled in as a fixed loop length.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "kernels.h"

namespace relaygs {
namespace {

constexpr int kPlanes = 6;  // xy, xz, yz, xt, yt, zt
constexpr int kCommonChannels = 16;  // 4D-GS's multi-view channel count: a compiled-in case
// Which coordinate (x, y, z, t) indexes each plane's columns and rows.
constexpr int kColumnAxis[kPlanes] = {0, 0, 1, 0, 1, 2};
constexpr int kRowAxis[kPlanes] = {1, 2, 2, 3, 3, 3};

// Where a grid coordinate in [-1, 1] reads an axis of `size` samples: lower and upper
// index, the upper one's weight and d(index)/d(coordinate), 0 where the border clamps it.
template <typename T>
struct AxisSample {
  int64_t lo, hi;
  T w, slope;

  AxisSample() = default;
  AxisSample(T coordinate, int64_t size) {
    slope = T(0.5) * T(size - 1);
    T index = (coordinate + T(1)) * slope;
    if (!(index > T(0))) {  // also NaN
      index = T(0);
      slope = T(0);
    } else if (index >= T(size - 1)) {
      index = T(size - 1);
      slope = T(0);
    }
    lo = static_cast<int64_t>(std::floor(index));
    hi = std::min<int64_t>(lo + 1, size - 1);
    w = index - T(lo);
  }
};

// One level's planes (or their gradients: Value non-const), channel-last: spatial
// [3, R, R, C] and time [3, T, R, C].
template <typename Value>
struct Level {
  Value* spatial;
  Value* time;
  int64_t res, time_res, channels;

  Value* plane(int p) const {
    return p < 3 ? spatial + p * res * res * channels : time + (p - 3) * time_res * res * channels;
  }
};

// The four corners of one plane sample: offsets into the plane and bilinear weights.
template <typename T>
struct Corners {
  int64_t offset[4];  // (lo row, lo col), (lo, hi), (hi, lo), (hi, hi)
  T weight[4];

  Corners(const AxisSample<T>& col, const AxisSample<T>& row, int64_t width, int64_t channels) {
    offset[0] = (row.lo * width + col.lo) * channels;
    offset[1] = (row.lo * width + col.hi) * channels;
    offset[2] = (row.hi * width + col.lo) * channels;
    offset[3] = (row.hi * width + col.hi) * channels;
    weight[0] = (T(1) - col.w) * (T(1) - row.w);
    weight[1] = col.w * (T(1) - row.w);
    weight[2] = (T(1) - col.w) * row.w;
    weight[3] = col.w * row.w;
  }
};

// The four axis samples (x, y, z over the spatial resolution, t over the time rows) of a
// point at one level.
template <typename T>
void axis_samples(const T* coord, T time, const Level<const T>& level, AxisSample<T>* axes) {
  for (int a = 0; a < 3; ++a) axes[a] = AxisSample<T>(coord[a], level.res);
  axes[3] = AxisSample<T>(time, level.time_res);
}

// The channel count: kChannels when the kernel was compiled for it (fixed-length loops that
// the compiler unrolls into whole SIMD vectors), else the level's own.
template <int kChannels, typename Value>
int64_t channels_of(const Level<Value>& level) {
  return kChannels > 0 ? kChannels : level.channels;
}

// samples [6, C]: each plane's bilinear sample at the point.
template <int kChannels, typename T>
void sample_planes(const Level<const T>& level, const AxisSample<T>* axes, T* samples) {
  const int64_t C = channels_of<kChannels>(level);
  for (int p = 0; p < kPlanes; ++p) {
    const Corners<T> k(axes[kColumnAxis[p]], axes[kRowAxis[p]], level.res, C);
    const T* plane = level.plane(p);
    T* out = samples + p * C;
    #pragma omp simd
    for (int64_t c = 0; c < C; ++c) {
      out[c] = k.weight[0] * plane[k.offset[0] + c] + k.weight[1] * plane[k.offset[1] + c] +
               k.weight[2] * plane[k.offset[2] + c] + k.weight[3] * plane[k.offset[3] + c];
    }
  }
}

template <typename T>
std::vector<Level<T>> levels_of(const std::vector<at::Tensor>& spatial,
                                const std::vector<at::Tensor>& time) {
  using Value = std::remove_const_t<T>;
  std::vector<Level<T>> levels;
  for (size_t l = 0; l < spatial.size(); ++l) {
    levels.push_back({spatial[l].data_ptr<Value>(), time[l].data_ptr<Value>(),
                      spatial[l].size(1), time[l].size(1), spatial[l].size(3)});
  }
  return levels;
}

void check_inputs(const at::Tensor& coords, const at::Tensor& times,
                  const std::vector<at::Tensor>& spatial, const std::vector<at::Tensor>& time) {
  const auto dtype = coords.scalar_type();
  TORCH_CHECK(coords.device().is_cpu() && coords.is_contiguous() && coords.dim() == 2 &&
                  coords.size(1) == 3,
              "coords must be a contiguous CPU [N,3] tensor");
  TORCH_CHECK(times.is_contiguous() && times.scalar_type() == dtype && times.dim() == 1 &&
                  times.size(0) == coords.size(0),
              "times must be a contiguous [N] tensor of the coordinates' dtype");
  TORCH_CHECK(!spatial.empty() && spatial.size() == time.size(), "one time plane per level");
  for (size_t l = 0; l < spatial.size(); ++l) {
    const at::Tensor& s = spatial[l];
    const at::Tensor& t = time[l];
    TORCH_CHECK(s.is_contiguous() && s.scalar_type() == dtype && s.dim() == 4 &&
                    s.size(0) == 3 && s.size(1) == s.size(2),
                "spatial planes must be contiguous channel-last [3,R,R,C]");
    TORCH_CHECK(t.is_contiguous() && t.scalar_type() == dtype && t.dim() == 4 &&
                    t.size(0) == 3 && t.size(2) == s.size(1) && t.size(3) == s.size(3) &&
                    s.size(3) == spatial[0].size(3),
                "time planes must be contiguous channel-last [3,T,R,C] matching the level");
  }
}

template <int kChannels, typename T>
void forward_points(const std::vector<Level<const T>>& levels, const T* coord, const T* t,
                    int64_t n, T* out) {
  const int64_t L = static_cast<int64_t>(levels.size());
  const int64_t C = channels_of<kChannels>(levels[0]);
  at::parallel_for(0, n, 256, [&](int64_t begin, int64_t end) {
    std::vector<T> samples(kPlanes * C);
    AxisSample<T> axes[4];
    for (int64_t i = begin; i < end; ++i) {
      for (int64_t l = 0; l < L; ++l) {
        axis_samples(coord + 3 * i, t[i], levels[l], axes);
        sample_planes<kChannels>(levels[l], axes, samples.data());
        T* f = out + i * C * L + l * C;
        #pragma omp simd
        for (int64_t c = 0; c < C; ++c) f[c] = samples[c];
        for (int p = 1; p < kPlanes; ++p) {
          #pragma omp simd
          for (int64_t c = 0; c < C; ++c) f[c] *= samples[p * C + c];
        }
      }
    }
  });
}

// The backward's scatter over each worker's fixed share of the points into its own
// channel-last buffers (`buffers[worker]`: per level spatial, time), and dL/dcoords.
template <int kChannels, typename T>
void backward_points(const std::vector<Level<const T>>& levels,
                     const std::vector<std::vector<at::Tensor>>& buffers, const T* coord,
                     const T* t, const T* grad, int64_t n, T* grad_coord) {
  const int64_t L = static_cast<int64_t>(levels.size());
  const int64_t C = channels_of<kChannels>(levels[0]);
  const int64_t workers = static_cast<int64_t>(buffers.size());
  const int64_t chunk = (n + workers - 1) / workers;
  at::parallel_for(0, workers, 1, [&](int64_t first, int64_t last) {
    std::vector<T> samples(kPlanes * C), before(kPlanes * C), after(kPlanes * C);
    std::vector<T> grad_sample(C), axis_grad(3 * C);  // axis_grad: dL/d(x, y, z) per channel
    AxisSample<T> axes[4];
    for (int64_t worker = first; worker < last; ++worker) {
      std::vector<at::Tensor> own_spatial, own_time;
      for (int64_t l = 0; l < L; ++l) {
        own_spatial.push_back(buffers[worker][2 * l]);
        own_time.push_back(buffers[worker][2 * l + 1]);
      }
      const auto into = levels_of<T>(own_spatial, own_time);
      const int64_t stop = std::min(n, (worker + 1) * chunk);
      for (int64_t i = worker * chunk; i < stop; ++i) {
        std::fill(axis_grad.begin(), axis_grad.end(), T(0));
        for (int64_t l = 0; l < L; ++l) {
          const Level<const T>& level = levels[l];
          axis_samples(coord + 3 * i, t[i], level, axes);
          sample_planes<kChannels>(level, axes, samples.data());
          // before[p] = product of planes < p, after[p] = product of planes > p
          #pragma omp simd
          for (int64_t c = 0; c < C; ++c) {
            before[c] = T(1);
            after[(kPlanes - 1) * C + c] = T(1);
          }
          for (int p = 1; p < kPlanes; ++p) {
            #pragma omp simd
            for (int64_t c = 0; c < C; ++c) {
              before[p * C + c] = before[(p - 1) * C + c] * samples[(p - 1) * C + c];
              const int q = kPlanes - 1 - p;
              after[q * C + c] = after[(q + 1) * C + c] * samples[(q + 1) * C + c];
            }
          }
          const T* g = grad + i * C * L + l * C;
          for (int p = 0; p < kPlanes; ++p) {
            const AxisSample<T>& col = axes[kColumnAxis[p]];
            const AxisSample<T>& row = axes[kRowAxis[p]];
            const Corners<T> k(col, row, level.res, C);
            #pragma omp simd
            for (int64_t c = 0; c < C; ++c) {
              grad_sample[c] = g[c] * before[p * C + c] * after[p * C + c];
            }
            T* plane_grad = into[l].plane(p);
            for (int corner = 0; corner < 4; ++corner) {
              T* cell = plane_grad + k.offset[corner];
              const T w = k.weight[corner];
              #pragma omp simd
              for (int64_t c = 0; c < C; ++c) cell[c] += w * grad_sample[c];
            }
            const T* plane = level.plane(p);
            const T* v00 = plane + k.offset[0];
            const T* v01 = plane + k.offset[1];
            const T* v10 = plane + k.offset[2];
            const T* v11 = plane + k.offset[3];
            // per channel here, summed over channels once per point below: a running scalar
            // sum would be one serial chain the compiler may not reorder into SIMD lanes
            T* col_grad = axis_grad.data() + kColumnAxis[p] * C;
            #pragma omp simd
            for (int64_t c = 0; c < C; ++c) {
              col_grad[c] += col.slope * grad_sample[c] *
                             ((T(1) - row.w) * (v01[c] - v00[c]) + row.w * (v11[c] - v10[c]));
            }
            if (kRowAxis[p] < 3) {
              T* row_grad = axis_grad.data() + kRowAxis[p] * C;
              #pragma omp simd
              for (int64_t c = 0; c < C; ++c) {
                row_grad[c] += row.slope * grad_sample[c] *
                               ((T(1) - col.w) * (v10[c] - v00[c]) + col.w * (v11[c] - v01[c]));
              }
            }
          }
        }
        for (int a = 0; a < 3; ++a) {
          T sum = 0;
          for (int64_t c = 0; c < C; ++c) sum += axis_grad[a * C + c];
          grad_coord[3 * i + a] = sum;
        }
      }
    }
  });
}

}  // namespace

at::Tensor hexplane_forward(const at::Tensor& coords, const at::Tensor& times,
                            const std::vector<at::Tensor>& spatial,
                            const std::vector<at::Tensor>& time) {
  check_inputs(coords, times, spatial, time);
  const int64_t n = coords.size(0), C = spatial[0].size(3);
  const int64_t L = static_cast<int64_t>(spatial.size());
  at::Tensor features = at::empty({n, C * L}, coords.options());
  AT_DISPATCH_FLOATING_TYPES(coords.scalar_type(), "hexplane_forward", [&] {
    using T = scalar_t;
    const auto levels = levels_of<const T>(spatial, time);
    const T* coord = coords.data_ptr<T>();
    const T* t = times.data_ptr<T>();
    T* out = features.data_ptr<T>();
    if (C == kCommonChannels) {
      forward_points<kCommonChannels>(levels, coord, t, n, out);
    } else {
      forward_points<0>(levels, coord, t, n, out);
    }
  });
  return features;
}

std::vector<at::Tensor> hexplane_backward(const at::Tensor& coords, const at::Tensor& times,
                                          const std::vector<at::Tensor>& spatial,
                                          const std::vector<at::Tensor>& time,
                                          const at::Tensor& grad_features) {
  check_inputs(coords, times, spatial, time);
  const int64_t n = coords.size(0), C = spatial[0].size(3);
  const int64_t L = static_cast<int64_t>(spatial.size());
  TORCH_CHECK(grad_features.is_contiguous() && grad_features.scalar_type() == coords.scalar_type() &&
                  grad_features.sizes() == at::IntArrayRef({n, C * L}),
              "grad_features must be a contiguous [N, C*levels] tensor");
  // One channel-last gradient buffer per worker and plane tensor (levels × spatial, time).
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n / 512));
  std::vector<std::vector<at::Tensor>> buffers(workers);
  for (auto& buffer : buffers) {
    for (int64_t l = 0; l < L; ++l) {
      buffer.push_back(at::zeros_like(spatial[l]));
      buffer.push_back(at::zeros_like(time[l]));
    }
  }
  at::Tensor grad_coords = at::zeros_like(coords);
  AT_DISPATCH_FLOATING_TYPES(coords.scalar_type(), "hexplane_backward", [&] {
    using T = scalar_t;
    const auto levels = levels_of<const T>(spatial, time);
    const T* coord = coords.data_ptr<T>();
    const T* t = times.data_ptr<T>();
    const T* grad = grad_features.data_ptr<T>();
    T* grad_coord = grad_coords.data_ptr<T>();
    if (C == kCommonChannels) {
      backward_points<kCommonChannels>(levels, buffers, coord, t, grad, n, grad_coord);
    } else {
      backward_points<0>(levels, buffers, coord, t, grad, n, grad_coord);
    }
  });
  // Sum the workers' buffers in worker order, written back channel-first [3, C, H, W].
  std::vector<at::Tensor> grads;
  for (int64_t b = 0; b < 2 * L; ++b) {
    const at::Tensor& like = buffers[0][b];
    const int64_t rows = like.size(1), cols = like.size(2);
    at::Tensor out = at::empty({3, C, rows, cols}, like.options());
    AT_DISPATCH_FLOATING_TYPES(like.scalar_type(), "hexplane_reduce", [&] {
      using T = scalar_t;
      std::vector<const T*> parts;
      for (const auto& buffer : buffers) parts.push_back(buffer[b].template data_ptr<T>());
      T* dst = out.data_ptr<T>();
      at::parallel_for(0, 3 * rows, 16, [&](int64_t begin, int64_t end) {
        for (int64_t pr = begin; pr < end; ++pr) {
          const int64_t p = pr / rows, r = pr % rows;
          // channel outer: contiguous writes, reads from one row of cells that stays cached
          const int64_t row_start = (p * rows + r) * cols * C;
          for (int64_t c = 0; c < C; ++c) {
            T* out_row = dst + ((p * C + c) * rows + r) * cols;
            for (int64_t x = 0; x < cols; ++x) {
              T sum = parts[0][row_start + x * C + c];
              for (size_t w = 1; w < parts.size(); ++w) sum += parts[w][row_start + x * C + c];
              out_row[x] = sum;
            }
          }
        }
      });
    });
    grads.push_back(out);
  }
  grads.push_back(grad_coords);
  return grads;
}

}  // namespace relaygs
