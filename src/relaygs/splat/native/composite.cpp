// Fused CPU compositing of binned screen-space Gaussians, forward and backward.
//
// One tile per task (threads take tiles from a shared counter). The pixels of a tile are
// held in explicit SIMD vectors (GCC/Clang vector extensions as wide as the target's
// registers: 64 bytes with AVX-512, 32 with AVX2, else 16), so every per-pair step is
// branch-free vector arithmetic with masks; blocks of pixels a pair cannot change (outside
// its box, or every pixel already stopped) are skipped. The forward walks a tile's
// depth-ordered list front to back with the early stop and keeps per pixel only the final
// transmittance and the index of the last composited pair. The backward walks back to
// front, recovering each pair's transmittance by division, and writes one gradient row per
// pair (summed over the tile's pixels in a fixed lane order); the caller adds the rows into
// per-Gaussian gradients in pair order, so results do not depend on the thread count.
// Numerics are those of relaygs.splat.composite (docs/splatting.md).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "kernels.h"

namespace relaygs {
namespace {

constexpr double kAlphaMin = 1.0 / 255.0;
constexpr double kAlphaMax = 0.99;
constexpr double kTransMin = 1e-4;
constexpr double kMaxPower = 40.0;
constexpr int64_t kGradColumns = 6;  // mean x, mean y, conic A, B, C, opacity
// Padding lanes sit this far left of and above the image: outside every pixel box.
constexpr double kFarAway = -1e6;
// The bounds of a block with no pixel in the image: no box meets them.
constexpr double kEmptyLo = 1e30, kEmptyHi = -1e30;

// Columns of the packed per-Gaussian table (relaygs.splat.composite._pack).
enum Column { kMx, kMy, kA, kB, kC, kOpacity, kX0, kX1, kY0, kY1, kColumns };

// Bytes of one vector: the target's register width. GCC expands wider vector types piecewise,
// partly lane by lane: 64-byte vectors ran the kernel 9× slower on an AVX2-only CPU.
#if defined(__AVX512F__)
constexpr int kVectorBytes = 64;
#elif defined(__AVX2__)
constexpr int kVectorBytes = 32;
#else
constexpr int kVectorBytes = 16;
#endif

// Vector types of one scalar type: V holds lanes of values, M lanes of masks (all bits set
// = true) and of the int32/int64 pair indices; comparisons of V give M.
template <typename scalar_t>
struct Simd;

template <>
struct Simd<float> {
  typedef float V __attribute__((vector_size(kVectorBytes)));
  typedef int32_t Lane;
  typedef Lane M __attribute__((vector_size(kVectorBytes)));
  static constexpr int64_t kLanes = kVectorBytes / sizeof(float);

  // exp(-p) for p in [0, 40]: 2^n·e^r with |r| <= ln2/2 and a degree-6 polynomial for e^r
  // (about 1 ulp; libm's expf would be one call per lane).
  static V exp_neg(V p) {
    const V x = -p;
    const V t = x * 1.44269504088896341f;
    const V n = (t + 12582912.0f) - 12582912.0f;  // round to nearest: |t| < 2^22
    V r = x - n * 0.693359375f;
    r = r + n * 2.12194440e-4f;
    V y = r * 1.9875691500e-4f + 1.3981999507e-3f;
    y = y * r + 8.3334519073e-3f;
    y = y * r + 4.1665795894e-2f;
    y = y * r + 1.6666665459e-1f;
    y = y * r + 5.0000001201e-1f;
    y = y * r * r + r + 1.0f;
    const M bits = (__builtin_convertvector(n, M) + 127) << 23;  // n in [-58, 0]: normal
    return y * reinterpret_cast<const V&>(bits);
  }
};

template <>
struct Simd<double> {
  typedef double V __attribute__((vector_size(kVectorBytes)));
  typedef int64_t Lane;
  typedef Lane M __attribute__((vector_size(kVectorBytes)));
  static constexpr int64_t kLanes = kVectorBytes / sizeof(double);

  // float64 serves the exactness tests, not speed: libm's exp lane by lane.
  static V exp_neg(V p) {
    V out;
    for (int64_t l = 0; l < kLanes; ++l) out[l] = std::exp(-p[l]);
    return out;
  }
};

struct Layout {
  int64_t tile_size, tiles_x, tiles_y, width, height, channels;

  int64_t pixels() const { return tile_size * tile_size; }
};

// The pixels of one tile in vectors of lanes (padded to whole vectors): coordinates, their
// flat index in a [C,H,W] image, and whether they lie inside the image (edge tiles are
// partly padding, as are the lanes past the tile's last pixel).
template <typename scalar_t>
struct TilePixels {
  using V = typename Simd<scalar_t>::V;
  static constexpr int64_t W = Simd<scalar_t>::kLanes;

  int64_t blocks;
  std::vector<V> col, row;
  std::vector<int64_t> index;
  std::vector<uint8_t> inside;
  // Per block, the box of its pixels inside the image (empty: lo > hi).
  std::vector<scalar_t> col_lo, col_hi, row_lo, row_hi;

  TilePixels(int64_t tile, const Layout& layout)
      : blocks((layout.pixels() + W - 1) / W), col(blocks), row(blocks),
        index(blocks * W), inside(blocks * W), col_lo(blocks, kEmptyLo),
        col_hi(blocks, kEmptyHi), row_lo(blocks, kEmptyLo), row_hi(blocks, kEmptyHi) {
    const int64_t per_camera = layout.tiles_x * layout.tiles_y;
    const int64_t camera = tile / per_camera;
    const int64_t local = tile % per_camera;
    const int64_t x0 = (local % layout.tiles_x) * layout.tile_size;
    const int64_t y0 = (local / layout.tiles_x) * layout.tile_size;
    for (int64_t p = 0; p < blocks * W; ++p) {
      const int64_t x = x0 + p % layout.tile_size;
      const int64_t y = y0 + p / layout.tile_size;
      const bool ok = p < layout.pixels() && x < layout.width && y < layout.height;
      inside[p] = ok;
      col[p / W][p % W] = ok ? static_cast<scalar_t>(x) : scalar_t(kFarAway);
      row[p / W][p % W] = ok ? static_cast<scalar_t>(y) : scalar_t(kFarAway);
      index[p] = ok ? (camera * layout.height + y) * layout.width + x : 0;
      if (ok) {
        const int64_t b = p / W;
        col_lo[b] = std::min<scalar_t>(col_lo[b], x);
        col_hi[b] = std::max<scalar_t>(col_hi[b], x);
        row_lo[b] = std::min<scalar_t>(row_lo[b], y);
        row_hi[b] = std::max<scalar_t>(row_hi[b], y);
      }
    }
  }

  // Whether Gaussian g's pixel box meets block b's: a block it misses has no lane in the
  // box, so the pair composites nothing there and is skipped (the same result, exactly).
  bool reaches(const scalar_t* g, int64_t b) const {
    return g[kX0] <= col_hi[b] && g[kX1] >= col_lo[b] && g[kY0] <= row_hi[b] &&
           g[kY1] >= row_lo[b];
  }
};

// What one Gaussian does at a vector of pixels: offsets, exp(-power), raw and clamped
// alpha, and whether each pair is composited at all (inside the box, power >= 0,
// alpha >= 1/255).
template <typename scalar_t>
struct PairValues {
  using S = Simd<scalar_t>;
  using V = typename S::V;
  using M = typename S::M;

  V dx, dy, gauss, alpha_raw, alpha;
  M composited;

  PairValues(const scalar_t* g, const V& col, const V& row) {
    const scalar_t zero = 0, max_power = kMaxPower, alpha_max = kAlphaMax;
    dx = col + scalar_t(0.5) - g[kMx];
    dy = row + scalar_t(0.5) - g[kMy];
    const V power = scalar_t(0.5) * g[kA] * dx * dx + g[kB] * dx * dy +
                    scalar_t(0.5) * g[kC] * dy * dy;
    const M in_box = (col >= g[kX0]) & (col <= g[kX1]) & (row >= g[kY0]) & (row <= g[kY1]);
    const V positive = power > zero ? power : zero;
    gauss = S::exp_neg(positive < max_power ? positive : max_power);
    alpha_raw = g[kOpacity] * gauss;
    alpha = alpha_raw < alpha_max ? alpha_raw : alpha_max;
    composited = in_box & (power >= zero) & (alpha >= scalar_t(kAlphaMin));
  }
};

// The sum of a vector's lanes, in lane order (deterministic).
template <typename Vec>
auto lane_sum(const Vec& v, int64_t lanes) {
  auto sum = v[0];
  for (int64_t l = 1; l < lanes; ++l) sum += v[l];
  return sum;
}

// Whether every lane of mask m is set (true = all bits set).
template <typename Mask>
bool all_lanes(const Mask& m) {
  uint64_t words[sizeof(Mask) / 8];
  std::memcpy(words, &m, sizeof(Mask));
  uint64_t both = ~uint64_t{0};
  for (uint64_t word : words) both &= word;
  return both == ~uint64_t{0};
}

// Runs body(task) over every listed tile, each worker taking the next from a shared
// counter (lists differ widely in length, so static chunks would leave threads idle).
template <typename Body>
void for_each_tile(int64_t count, const Body& body) {
  std::atomic<int64_t> next{0};
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), count));
  at::parallel_for(0, workers, 1, [&](int64_t begin, int64_t end) {
    for (int64_t worker = begin; worker < end; ++worker) {
      for (int64_t i = next.fetch_add(1); i < count; i = next.fetch_add(1)) body(i);
    }
  });
}

template <typename scalar_t>
struct Inputs {
  const scalar_t* table;
  const scalar_t* colors;
  const int64_t* pairs;
  const int64_t* start;
  const int64_t* count;
  const int64_t* tiles;
};

template <typename scalar_t>
Inputs<scalar_t> inputs_of(const at::Tensor& table, const at::Tensor& colors,
                           const at::Tensor& pair_gaussian, const at::Tensor& tile_start,
                           const at::Tensor& tile_count, const at::Tensor& tiles) {
  return {table.data_ptr<scalar_t>(), colors.data_ptr<scalar_t>(),
          pair_gaussian.data_ptr<int64_t>(), tile_start.data_ptr<int64_t>(),
          tile_count.data_ptr<int64_t>(), tiles.data_ptr<int64_t>()};
}

// Front to back through one tile's list; writes its pixels of out, t_final and last.
template <typename scalar_t>
void forward_tile(const Inputs<scalar_t>& in, int64_t tile, const Layout& layout,
                  scalar_t* out, scalar_t* t_final, int32_t* last) {
  using S = Simd<scalar_t>;
  using V = typename S::V;
  using M = typename S::M;
  constexpr int64_t W = S::kLanes;
  const int64_t D = layout.channels;
  const TilePixels<scalar_t> pix(tile, layout);
  const int64_t B = pix.blocks;
  const scalar_t zero = 0, one = 1;
  std::vector<V> trans(B, V{} + one), weight(B), acc(D * B, V{});
  std::vector<M> last_hit(B, M{} - 1), done(B);
  std::vector<uint8_t> reached(B), closed(B);  // closed: every lane has stopped
  int64_t finished = 0;
  for (int64_t p = 0; p < B * W; ++p) {
    done[p / W][p % W] = pix.inside[p] ? 0 : -1;
    finished += !pix.inside[p];
  }
  for (int64_t b = 0; b < B; ++b) closed[b] = all_lanes(done[b]);
  const int64_t start = in.start[tile];
  const int64_t count = in.count[tile];
  for (int64_t i = 0; i < count && finished < B * W; ++i) {
    const int64_t gid = in.pairs[start + i];
    const scalar_t* g = in.table + gid * kColumns;
    M stopped{};
    for (int64_t b = 0; b < B; ++b) {
      reached[b] = !closed[b] && pix.reaches(g, b);
      if (!reached[b]) continue;
      const PairValues<scalar_t> pv(g, pix.col[b], pix.row[b]);
      const M live = pv.composited & ~done[b];
      const V next = trans[b] * (one - pv.alpha);
      const M stop = live & (next < scalar_t(kTransMin));
      const M take = live & ~stop;
      weight[b] = take ? pv.alpha * trans[b] : zero;
      trans[b] = take ? next : trans[b];
      last_hit[b] = take ? static_cast<typename S::Lane>(i) : last_hit[b];
      done[b] |= stop;
      stopped -= stop;
      closed[b] = all_lanes(done[b]);
    }
    finished += lane_sum(stopped, W);
    const scalar_t* c = in.colors + gid * D;
    for (int64_t ch = 0; ch < D; ++ch) {
      for (int64_t b = 0; b < B; ++b) {
        if (reached[b]) acc[ch * B + b] += weight[b] * c[ch];
      }
    }
  }
  for (int64_t p = 0; p < B * W; ++p) {
    if (!pix.inside[p]) continue;
    const int64_t at = pix.index[p];
    t_final[at] = trans[p / W][p % W];
    last[at] = static_cast<int32_t>(last_hit[p / W][p % W]);
    for (int64_t ch = 0; ch < D; ++ch) out[at * D + ch] = acc[ch * B + p / W][p % W];
  }
}

// What the backward reads per pixel besides the pairs.
template <typename scalar_t>
struct PixelGrads {
  const scalar_t* grad_out;  // [C,H,W,D]
  const scalar_t* k;         // [C,H,W]
  const scalar_t* t_final;   // [C,H,W]
  const int32_t* last;       // [C,H,W]
};

// Back to front through one tile's list; writes one gradient row per pair up to the
// deepest one composited, and returns how many that is.
template <typename scalar_t>
int64_t backward_tile(const Inputs<scalar_t>& in, int64_t tile, const Layout& layout,
                   const PixelGrads<scalar_t>& px, scalar_t* pair_grads,
                   scalar_t* pair_colors) {
  using S = Simd<scalar_t>;
  using V = typename S::V;
  using M = typename S::M;
  constexpr int64_t W = S::kLanes;
  const int64_t D = layout.channels;
  const TilePixels<scalar_t> pix(tile, layout);
  const int64_t B = pix.blocks;
  const scalar_t zero = 0, one = 1, alpha_max = kAlphaMax;
  std::vector<V> trans(B), k(B), suffix(B), v(B), weight(B), g(D * B);
  std::vector<M> last_hit(B);
  std::vector<uint8_t> reached(B);
  std::vector<int32_t> block_deepest(B, -1);  // pairs deeper than a block's own skip it
  int32_t deepest = -1;
  for (int64_t p = 0; p < B * W; ++p) {
    const int64_t b = p / W, l = p % W, at = pix.index[p];
    const bool inside = pix.inside[p];
    trans[b][l] = inside ? px.t_final[at] : one;
    k[b][l] = inside ? px.k[at] : zero;
    last_hit[b][l] = inside ? px.last[at] : -1;
    block_deepest[b] =
        std::max<int32_t>(block_deepest[b], static_cast<int32_t>(last_hit[b][l]));
    deepest = std::max<int32_t>(deepest, block_deepest[b]);
    for (int64_t ch = 0; ch < D; ++ch) g[ch * B + b][l] = inside ? px.grad_out[at * D + ch] : 0;
  }
  const int64_t start = in.start[tile];
  for (int64_t i = deepest; i >= 0; --i) {
    const int64_t gid = in.pairs[start + i];
    const scalar_t* gauss = in.table + gid * kColumns;
    const scalar_t* c = in.colors + gid * D;
    // v = g·c per pixel: what this Gaussian's colour is worth to the loss there.
    for (int64_t b = 0; b < B; ++b) {
      reached[b] = i <= block_deepest[b] && pix.reaches(gauss, b);
    }
    std::fill(v.begin(), v.end(), V{});
    for (int64_t ch = 0; ch < D; ++ch) {
      for (int64_t b = 0; b < B; ++b) {
        if (reached[b]) v[b] += g[ch * B + b] * c[ch];
      }
    }
    V s_x{}, s_y{}, s_xx{}, s_xy{}, s_yy{}, s_opacity{};
    const auto index = static_cast<typename S::Lane>(i);
    for (int64_t b = 0; b < B; ++b) {
      if (!reached[b]) continue;
      const PairValues<scalar_t> pv(gauss, pix.col[b], pix.row[b]);
      const M hit = pv.composited & (last_hit[b] >= index);
      const V inverse = one / (one - pv.alpha);  // 1 − α >= 0.01
      const V before = trans[b] * inverse;
      const V w = pv.alpha * before;
      // dL/dα = v·T − (Σ_{j>i} v_j w_j + K) / (1 − α); the clamp at 0.99 passes none.
      const V d_alpha = (hit & (pv.alpha_raw < alpha_max))
                            ? v[b] * before - (suffix[b] + k[b]) * inverse
                            : zero;
      weight[b] = hit ? w : zero;
      suffix[b] = hit ? suffix[b] + v[b] * w : suffix[b];
      trans[b] = hit ? before : trans[b];
      const V d_power = -d_alpha * pv.alpha_raw;
      s_opacity += d_alpha * pv.gauss;
      s_x += d_power * pv.dx;
      s_y += d_power * pv.dy;
      s_xx += d_power * pv.dx * pv.dx;
      s_xy += d_power * pv.dx * pv.dy;
      s_yy += d_power * pv.dy * pv.dy;
    }
    const scalar_t sx = lane_sum(s_x, W), sy = lane_sum(s_y, W);
    scalar_t* row = pair_grads + (start + i) * kGradColumns;
    row[0] = -(gauss[kA] * sx + gauss[kB] * sy);
    row[1] = -(gauss[kB] * sx + gauss[kC] * sy);
    row[2] = scalar_t(0.5) * lane_sum(s_xx, W);
    row[3] = lane_sum(s_xy, W);
    row[4] = scalar_t(0.5) * lane_sum(s_yy, W);
    row[5] = lane_sum(s_opacity, W);
    scalar_t* row_c = pair_colors + (start + i) * D;
    for (int64_t ch = 0; ch < D; ++ch) {
      V sum{};
      for (int64_t b = 0; b < B; ++b) {
        if (reached[b]) sum += weight[b] * g[ch * B + b];
      }
      row_c[ch] = lane_sum(sum, W);
    }
  }
  return deepest + 1;
}

void check_common(const at::Tensor& table, const at::Tensor& colors,
                  const at::Tensor& pair_gaussian, const at::Tensor& tile_start,
                  const at::Tensor& tile_count, const at::Tensor& tiles) {
  TORCH_CHECK(table.device().is_cpu() && table.is_contiguous() && table.dim() == 2 &&
                  table.size(1) == kColumns,
              "table must be a contiguous CPU [G,10] tensor");
  TORCH_CHECK(colors.device().is_cpu() && colors.scalar_type() == table.scalar_type() &&
                  colors.is_contiguous() &&
                  colors.dim() == 2 && colors.size(0) == table.size(0),
              "colors must be a contiguous [G,D] tensor of the table's dtype");
  for (const at::Tensor* t : std::initializer_list<const at::Tensor*>{&pair_gaussian, &tile_start, &tile_count, &tiles}) {
    TORCH_CHECK(t->device().is_cpu() && t->scalar_type() == at::kLong && t->is_contiguous(),
                "index tensors must be contiguous CPU int64 tensors");
  }
}

Layout make_layout(int64_t tile_size, int64_t tiles_x, int64_t tiles_y, int64_t width,
                   int64_t height, int64_t channels) {
  TORCH_CHECK(tile_size >= 1 && tiles_x >= 1 && tiles_y >= 1 && width >= 1 && height >= 1,
              "bad tile layout");
  return Layout{tile_size, tiles_x, tiles_y, width, height, channels};
}

}  // namespace

// Composites `tiles` into out [C,H,W,D], t_final [C,H,W] and last [C,H,W] (int32), which
// hold the caller's values everywhere else (a fixed layer's render, or empty).
void composite_forward(const at::Tensor& table, const at::Tensor& colors,
                       const at::Tensor& pair_gaussian, const at::Tensor& tile_start,
                       const at::Tensor& tile_count, const at::Tensor& tiles, int64_t tile_size,
                       int64_t tiles_x, int64_t tiles_y, int64_t width, int64_t height,
                       at::Tensor out, at::Tensor t_final, at::Tensor last) {
  check_common(table, colors, pair_gaussian, tile_start, tile_count, tiles);
  TORCH_CHECK(out.device().is_cpu() && t_final.device().is_cpu() && last.device().is_cpu(),
              "outputs must be CPU tensors");
  TORCH_CHECK(out.is_contiguous() && t_final.is_contiguous() && last.is_contiguous() &&
                  out.scalar_type() == table.scalar_type() &&
                  t_final.scalar_type() == table.scalar_type() &&
                  last.scalar_type() == at::kInt,
              "outputs must be contiguous, of the table's dtype, last int32");
  const Layout layout = make_layout(tile_size, tiles_x, tiles_y, width, height, colors.size(1));
  AT_DISPATCH_FLOATING_TYPES(table.scalar_type(), "composite_forward", [&] {
    const auto in = inputs_of<scalar_t>(table, colors, pair_gaussian, tile_start, tile_count,
                                        tiles);
    scalar_t* out_p = out.data_ptr<scalar_t>();
    scalar_t* t_final_p = t_final.data_ptr<scalar_t>();
    int32_t* last_p = last.data_ptr<int32_t>();
    for_each_tile(tiles.numel(), [&](int64_t task) {
      forward_tile<scalar_t>(in, in.tiles[task], layout, out_p, t_final_p, last_p);
    });
  });
}

// Gradients per Gaussian row of the table: [G,6] (mean x/y, conic A/B/C, opacity) and of
// colours [G,D]. Each tile writes its pairs' rows in parallel; the rows are then added into
// the Gaussians' in tile-list and pair order, one thread, so the sums are deterministic.
std::vector<at::Tensor> composite_backward(
    const at::Tensor& table, const at::Tensor& colors, const at::Tensor& pair_gaussian,
    const at::Tensor& tile_start, const at::Tensor& tile_count, const at::Tensor& tiles,
    int64_t tile_size, int64_t tiles_x, int64_t tiles_y, int64_t width, int64_t height,
    const at::Tensor& grad_out, const at::Tensor& pixel_k, const at::Tensor& t_final,
    const at::Tensor& last) {
  check_common(table, colors, pair_gaussian, tile_start, tile_count, tiles);
  for (const at::Tensor* t : std::initializer_list<const at::Tensor*>{&grad_out, &pixel_k,
                                                                      &t_final}) {
    TORCH_CHECK(t->device().is_cpu() && t->is_contiguous() &&
                    t->scalar_type() == table.scalar_type(),
                "backward tensors must be contiguous CPU tensors of the table's dtype");
  }
  TORCH_CHECK(last.device().is_cpu() && last.is_contiguous() && last.scalar_type() == at::kInt,
              "last must be a CPU int32 tensor");
  const Layout layout = make_layout(tile_size, tiles_x, tiles_y, width, height, colors.size(1));
  const int64_t D = layout.channels;
  at::Tensor pair_grads = at::empty({pair_gaussian.numel(), kGradColumns}, table.options());
  at::Tensor pair_colors = at::empty({pair_gaussian.numel(), D}, table.options());
  at::Tensor grads = at::zeros({table.size(0), kGradColumns}, table.options());
  at::Tensor grad_colors = at::zeros({table.size(0), D}, table.options());
  AT_DISPATCH_FLOATING_TYPES(table.scalar_type(), "composite_backward", [&] {
    const auto in = inputs_of<scalar_t>(table, colors, pair_gaussian, tile_start, tile_count,
                                        tiles);
    const PixelGrads<scalar_t> px{grad_out.data_ptr<scalar_t>(), pixel_k.data_ptr<scalar_t>(),
                                  t_final.data_ptr<scalar_t>(), last.data_ptr<int32_t>()};
    scalar_t* rows = pair_grads.data_ptr<scalar_t>();
    scalar_t* rows_c = pair_colors.data_ptr<scalar_t>();
    std::vector<int64_t> reached(tiles.numel());
    for_each_tile(tiles.numel(), [&](int64_t task) {
      reached[task] = backward_tile<scalar_t>(in, in.tiles[task], layout, px, rows, rows_c);
    });
    scalar_t* out = grads.data_ptr<scalar_t>();
    scalar_t* out_c = grad_colors.data_ptr<scalar_t>();
    for (int64_t task = 0; task < tiles.numel(); ++task) {
      const int64_t start = in.start[in.tiles[task]];
      for (int64_t pair = start; pair < start + reached[task]; ++pair) {
        const int64_t gid = in.pairs[pair];
        for (int64_t j = 0; j < kGradColumns; ++j) {
          out[gid * kGradColumns + j] += rows[pair * kGradColumns + j];
        }
        for (int64_t ch = 0; ch < D; ++ch) out_c[gid * D + ch] += rows_c[pair * D + ch];
      }
    }
  });
  return {grads, grad_colors};
}

}  // namespace relaygs
