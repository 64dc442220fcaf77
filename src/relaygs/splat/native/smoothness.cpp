// Second-difference smoothness of HexPlane planes (relaygs.field.hexplane), energy and
// gradient in one pass.
//
// For planes [P, C, H, W] and an axis (2: H, 3: W), the curvature c_j = x_j - 2 x_{j+1} +
// x_{j+2} along that axis gives the energy sum_p mean(c^2) = sum(c^2) / M (M: curvatures per
// plane) and the gradient (2/M) D^T c, i.e. g_j = (2/M)(c_j - 2 c_{j-1} + c_{j-2}); with both
// axes, their energies and gradients add. Each (plane, channel) slice is one task; its energy
// is summed in double and the slices' sums are added in order, so the result does not depend
// on the thread count.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <vector>

#include "kernels.h"

namespace relaygs {
namespace {

// One slice [H, W]: curvature along H (rows of W contiguous values), gradient rows added.
template <typename T>
double along_rows(const T* __restrict x, T* __restrict g, int64_t H, int64_t W, T scale) {
  double energy = 0.0;
  for (int64_t j = 0; j + 2 < H; ++j) {
    const T* r0 = x + j * W;
    const T* r1 = r0 + W;
    const T* r2 = r1 + W;
    T* g0 = g + j * W;
    T* g1 = g0 + W;
    T* g2 = g1 + W;
    T row = T(0);
    for (int64_t w = 0; w < W; ++w) {
      const T c = r0[w] - T(2) * r1[w] + r2[w];
      row += c * c;
      const T s = scale * c;
      g0[w] += s;
      g1[w] -= T(2) * s;
      g2[w] += s;
    }
    energy += static_cast<double>(row);
  }
  return energy;
}

// One slice [H, W]: curvature along W within each row, written to `curvature` first so the
// gradient row (added) is a stencil over it.
template <typename T>
double along_columns(const T* __restrict x, T* __restrict g, int64_t H, int64_t W, T scale,
                     T* __restrict curvature) {
  double energy = 0.0;
  const int64_t n = W - 2;
  for (int64_t h = 0; h < H; ++h) {
    const T* r = x + h * W;
    T* gr = g + h * W;
    T row = T(0);
    for (int64_t w = 0; w < n; ++w) {
      const T c = r[w] - T(2) * r[w + 1] + r[w + 2];
      curvature[w] = c;
      row += c * c;
    }
    energy += static_cast<double>(row);
    for (int64_t w = 0; w < W; ++w) {
      const T here = w < n ? curvature[w] : T(0);
      const T one_back = (w >= 1 && w - 1 < n) ? curvature[w - 1] : T(0);
      const T two_back = w >= 2 ? curvature[w - 2] : T(0);
      gr[w] += scale * (here - T(2) * one_back + two_back);
    }
  }
  return energy;
}

}  // namespace

std::vector<at::Tensor> second_difference(const at::Tensor& planes, bool rows, bool columns) {
  TORCH_CHECK(planes.dim() == 4, "second_difference: planes must be [P, C, H, W]");
  TORCH_CHECK(rows || columns, "second_difference: no axis chosen");
  TORCH_CHECK(!rows || planes.size(2) >= 3, "second_difference: H needs 3 samples or more");
  TORCH_CHECK(!columns || planes.size(3) >= 3, "second_difference: W needs 3 samples or more");
  const at::Tensor x = planes.contiguous();
  const int64_t C = x.size(1), H = x.size(2), W = x.size(3);
  const int64_t slices = x.size(0) * C;
  const double along_h = static_cast<double>(C) * (H - 2) * W;  // curvatures per plane
  const double along_w = static_cast<double>(C) * H * (W - 2);
  at::Tensor grad = at::zeros_like(x);
  std::vector<double> energies(static_cast<size_t>(2 * slices), 0.0);
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "second_difference", [&] {
    const scalar_t* in = x.data_ptr<scalar_t>();
    scalar_t* out = grad.data_ptr<scalar_t>();
    at::parallel_for(0, slices, 1, [&](int64_t begin, int64_t end) {
      std::vector<scalar_t> curvature(static_cast<size_t>(W));
      for (int64_t s = begin; s < end; ++s) {
        const scalar_t* slice = in + s * H * W;
        scalar_t* slice_grad = out + s * H * W;
        if (rows) {
          const auto scale = static_cast<scalar_t>(2.0 / along_h);
          energies[static_cast<size_t>(2 * s)] = along_rows(slice, slice_grad, H, W, scale);
        }
        if (columns) {
          const auto scale = static_cast<scalar_t>(2.0 / along_w);
          energies[static_cast<size_t>(2 * s + 1)] =
              along_columns(slice, slice_grad, H, W, scale, curvature.data());
        }
      }
    });
  });
  double rows_total = 0.0, columns_total = 0.0;
  for (int64_t s = 0; s < slices; ++s) {
    rows_total += energies[static_cast<size_t>(2 * s)];
    columns_total += energies[static_cast<size_t>(2 * s + 1)];
  }
  const double energy = (rows ? rows_total / along_h : 0.0) +
                        (columns ? columns_total / along_w : 0.0);
  return {at::scalar_tensor(energy, x.options()), grad};
}

}  // namespace relaygs
