// Nearest neighbours by brute force: for each query point the index of the closest of a
// point set (relaygs.nearest; the frame hulls' distance terms).
//
// Each query scans every point without a [Q, P] distance matrix: LANES running minima, one per
// lane of a SIMD vector, over the points in blocks of LANES, then the lanes' minima reduced.
// The points are read as separate x, y, z arrays so a block is three contiguous loads. A lane
// keeps the first point of its smallest distance (strict <) and the reduction the smallest
// index among equal minima, so ties go to the first point, as argmin's do. Queries are split
// across threads; each writes its own row, so the result does not depend on the thread count.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <limits>

#include "kernels.h"

namespace relaygs {
namespace {

constexpr int64_t LANES = 16;

template <typename T>
int64_t nearest_one(T qx, T qy, T qz, const T* __restrict x, const T* __restrict y,
                    const T* __restrict z, int64_t count) {
  T best[LANES];
  int64_t index[LANES];
  for (int64_t l = 0; l < LANES; ++l) {
    best[l] = std::numeric_limits<T>::infinity();
    index[l] = -1;
  }
  const int64_t blocks = count / LANES * LANES;
  for (int64_t j = 0; j < blocks; j += LANES) {
    for (int64_t l = 0; l < LANES; ++l) {
      const T dx = qx - x[j + l];
      const T dy = qy - y[j + l];
      const T dz = qz - z[j + l];
      const T d = dx * dx + dy * dy + dz * dz;
      const bool closer = d < best[l];
      best[l] = closer ? d : best[l];
      index[l] = closer ? j + l : index[l];
    }
  }
  for (int64_t j = blocks; j < count; ++j) {
    const T dx = qx - x[j];
    const T dy = qy - y[j];
    const T dz = qz - z[j];
    const T d = dx * dx + dy * dy + dz * dz;
    const int64_t l = j - blocks;
    if (d < best[l]) {
      best[l] = d;
      index[l] = j;
    }
  }
  // a NaN distance never wins, so a lane may end without a point: start from the first one
  T winner_distance = std::numeric_limits<T>::infinity();
  int64_t winner = 0;
  bool found = false;
  for (int64_t l = 0; l < LANES; ++l) {
    if (index[l] < 0) continue;
    if (!found || best[l] < winner_distance ||
        (best[l] == winner_distance && index[l] < winner)) {
      winner_distance = best[l];
      winner = index[l];
      found = true;
    }
  }
  return winner;
}

template <typename T>
void nearest_all(const at::Tensor& queries, const at::Tensor& points, at::Tensor& out) {
  const int64_t count = points.size(0);
  const at::Tensor columns = points.t().contiguous();  // [3, P]: x, y, z arrays
  const T* x = columns.data_ptr<T>();
  const T* y = x + count;
  const T* z = y + count;
  const T* q = queries.data_ptr<T>();
  int64_t* result = out.data_ptr<int64_t>();
  at::parallel_for(0, queries.size(0), 16, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      result[i] = nearest_one<T>(q[3 * i], q[3 * i + 1], q[3 * i + 2], x, y, z, count);
    }
  });
}

}  // namespace

at::Tensor nearest_points(const at::Tensor& queries, const at::Tensor& points) {
  for (const at::Tensor* tensor : {&queries, &points}) {
    TORCH_CHECK(tensor->device().is_cpu() && tensor->is_contiguous() && tensor->dim() == 2 &&
                    tensor->size(1) == 3,
                "nearest_points: expected contiguous CPU tensors [N, 3]");
  }
  TORCH_CHECK(queries.scalar_type() == points.scalar_type(),
              "nearest_points: queries and points differ in dtype");
  TORCH_CHECK(points.size(0) >= 1, "nearest_points: no points to search");
  at::Tensor out = at::empty({queries.size(0)}, queries.options().dtype(at::kLong));
  if (queries.scalar_type() == at::kFloat) {
    nearest_all<float>(queries, points, out);
  } else {
    TORCH_CHECK(queries.scalar_type() == at::kDouble,
                "nearest_points: expected float32 or float64");
    nearest_all<double>(queries, points, out);
  }
  return out;
}

}  // namespace relaygs
