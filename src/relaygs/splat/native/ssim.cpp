// Native SSIM of channel-last image batches, forward and the gradient with respect to the
// first images (relaygs.metrics.ssim: 11-tap Gaussian window, σ 1.5, zero padding, C1 0.01²,
// C2 0.03², the mean over every pixel and channel).
//
// Blurs are separable passes over rows of W·C contiguous values, one image row per task, so
// the compiler vectorises the inner loops. The backward takes the five blurred maps the
// forward kept, forms the per-pixel derivatives of the SSIM map with respect to μx, E[x²]
// and E[xy], and blurs them back (the zero-padded symmetric window is its own adjoint):
//   dL/dx = blur(∂S/∂μx) + 2x·blur(∂S/∂E[x²]) + y·blur(∂S/∂E[xy]), times dL/dmean / count.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "kernels.h"

namespace relaygs {
namespace {

constexpr int kTaps = 11;
constexpr int kHalf = kTaps / 2;
constexpr double kSigma = 1.5;
constexpr double kC1 = 0.01 * 0.01;
constexpr double kC2 = 0.03 * 0.03;

template <typename T>
std::vector<T> window() {
  std::vector<double> w(kTaps);
  double total = 0;
  for (int k = 0; k < kTaps; ++k) {
    const double offset = k - kHalf;
    w[k] = std::exp(-(offset * offset) / (2 * kSigma * kSigma));
    total += w[k];
  }
  std::vector<T> out(kTaps);
  for (int k = 0; k < kTaps; ++k) out[k] = static_cast<T>(w[k] / total);
  return out;
}

struct Shape {
  int64_t images, height, width, channels;

  int64_t row() const { return width * channels; }
  int64_t plane() const { return height * row(); }
  int64_t size() const { return images * plane(); }
};

// out = the 2D Gaussian blur of `maps` images of `shape` (zero padding), via `scratch`.
template <typename T>
void blur(const T* in, T* out, T* scratch, int64_t maps, const Shape& s, const T* w) {
  const int64_t row = s.row(), C = s.channels;
  const int64_t rows = maps * s.images * s.height;
  at::parallel_for(0, rows, 16, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const T* src = in + r * row;
      T* dst = scratch + r * row;
      for (int64_t j = 0; j < row; ++j) dst[j] = T(0);
      for (int k = 0; k < kTaps; ++k) {
        const int64_t shift = (k - kHalf) * C;  // dst[j] += w[k]·src[j + shift]
        const int64_t lo = std::max<int64_t>(0, -shift), hi = std::min(row, row - shift);
        for (int64_t j = lo; j < hi; ++j) dst[j] += w[k] * src[j + shift];
      }
    }
  });
  at::parallel_for(0, rows, 16, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const int64_t y = r % s.height;
      T* dst = out + r * row;
      for (int64_t j = 0; j < row; ++j) dst[j] = T(0);
      for (int k = 0; k < kTaps; ++k) {
        const int64_t source = y + k - kHalf;
        if (source < 0 || source >= s.height) continue;
        const T* src = scratch + (r + k - kHalf) * row;
        for (int64_t j = 0; j < row; ++j) dst[j] += w[k] * src[j];
      }
    }
  });
}

// The five blurred maps μx, μy, E[x²], E[y²], E[xy] of x and y into `out` (5·s.size()).
template <typename T>
void moments(const T* x, const T* y, const Shape& s, const T* w, T* out) {
  const int64_t n = s.size();
  std::vector<T> raw(5 * n), scratch(5 * n);
  at::parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      raw[i] = x[i];
      raw[n + i] = y[i];
      raw[2 * n + i] = x[i] * x[i];
      raw[3 * n + i] = y[i] * y[i];
      raw[4 * n + i] = x[i] * y[i];
    }
  });
  blur(raw.data(), out, scratch.data(), 5, s, w);
}

Shape check(const at::Tensor& x, const at::Tensor& y) {
  TORCH_CHECK(x.device().is_cpu() && x.is_contiguous() && y.is_contiguous() &&
                  x.sizes() == y.sizes() && x.scalar_type() == y.scalar_type() && x.dim() == 4,
              "ssim inputs must be contiguous CPU [B,H,W,C] tensors of one shape and dtype");
  return {x.size(0), x.size(1), x.size(2), x.size(3)};
}

}  // namespace

std::vector<at::Tensor> ssim_forward(const at::Tensor& x, const at::Tensor& y) {
  const Shape s = check(x, y);
  at::Tensor out = at::empty({}, x.options());
  at::Tensor blurred = at::empty({5, s.size()}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "ssim_forward", [&] {
    using T = scalar_t;
    const auto w = window<T>();
    const int64_t n = s.size();
    T* m = blurred.data_ptr<T>();
    moments(x.data_ptr<T>(), y.data_ptr<T>(), s, w.data(), m);
    double total = 0;  // in double, in index order: deterministic for any thread count
    for (int64_t i = 0; i < n; ++i) {
      const T mx = m[i], my = m[n + i];
      const T vx = m[2 * n + i] - mx * mx, vy = m[3 * n + i] - my * my;
      const T cov = m[4 * n + i] - mx * my;
      const T num = (T(2) * mx * my + T(kC1)) * (T(2) * cov + T(kC2));
      const T den = (mx * mx + my * my + T(kC1)) * (std::max(vx + vy, T(0)) + T(kC2));
      total += static_cast<double>(num / den);
    }
    out.fill_(total / static_cast<double>(n));
  });
  return {out, blurred};
}

at::Tensor ssim_backward(const at::Tensor& x, const at::Tensor& y, const at::Tensor& blurred,
                         const at::Tensor& grad) {
  const Shape s = check(x, y);
  TORCH_CHECK(blurred.is_contiguous() && blurred.numel() == 5 * s.size() &&
                  blurred.scalar_type() == x.scalar_type(),
              "blurred must be ssim_forward's [5, B*H*W*C] maps");
  at::Tensor grad_x = at::empty_like(x);
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "ssim_backward", [&] {
    using T = scalar_t;
    const auto w = window<T>();
    const int64_t n = s.size();
    const T* xs = x.data_ptr<T>();
    const T* ys = y.data_ptr<T>();
    const T* m = blurred.data_ptr<T>();
    const T scale = static_cast<T>(grad.item<double>() / static_cast<double>(n));
    // ∂S/∂μx, ∂S/∂E[x²], ∂S/∂E[xy] per pixel, scaled by dL/dmean / count
    std::vector<T> partial(3 * n), back(3 * n), scratch(3 * n);
    at::parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        const T mx = m[i], my = m[n + i];
        const T vx = m[2 * n + i] - mx * mx, vy = m[3 * n + i] - my * my;
        const T cov = m[4 * n + i] - mx * my;
        const T a = T(2) * mx * my + T(kC1), b = T(2) * cov + T(kC2);
        const T c = mx * mx + my * my + T(kC1);
        const bool spread = vx + vy >= T(0);  // clamp_min passes its gradient at 0
        const T d = (spread ? vx + vy : T(0)) + T(kC2);
        const T ssim = a * b / (c * d);
        const T d_a = b / (c * d), d_b = a / (c * d), d_c = -ssim / c;
        const T d_d = spread ? -ssim / d : T(0);
        partial[i] = scale * (T(2) * my * d_a - T(2) * my * d_b + T(2) * mx * d_c -
                              T(2) * mx * d_d);
        partial[n + i] = scale * d_d;
        partial[2 * n + i] = scale * T(2) * d_b;
      }
    });
    blur(partial.data(), back.data(), scratch.data(), 3, s, w.data());
    T* g = grad_x.data_ptr<T>();
    at::parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        g[i] = back[i] + T(2) * xs[i] * back[n + i] + ys[i] * back[2 * n + i];
      }
    });
  });
  return grad_x;
}

}  // namespace relaygs
