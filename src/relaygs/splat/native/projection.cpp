// Native EWA projection of 3D Gaussians into C cameras, forward and backward.
//
// The same numerics as relaygs.splat.projection (docs/splatting.md): near/far cull, the
// Jacobian at x/z clamped to the widened frustum, the eps2d blur, det from Lagrange's
// identity, the det and variance culls, opacity-aware pixel boxes. One Gaussian per task,
// all cameras in it: the backward sums a Gaussian's gradient over the cameras in camera
// order inside one task, so it needs no atomics and does not depend on the thread count.
// Forward and backward evaluate each (camera, Gaussian) pair with the same inlined function,
// so they agree on which pairs are visible.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "kernels.h"

namespace relaygs {
namespace {

// Constants of relaygs.splat.projection.
constexpr double kAlphaMin = 1.0 / 255.0;
constexpr double kMaxSigmaMult = 3.33;
constexpr double kFrustumMargin = 0.3;
constexpr double kMaxRatio = 1e30;
constexpr double kMaxVarPx = 1e14;
constexpr double kMaxPixel = 1073741824.0;  // 2^30: boxes and radii are clamped to it

// One camera: world→camera rotation (row-major) and translation, intrinsics and the
// clamp range of x/z and y/z (the frustum widened by the margin).
template <typename T>
struct Camera {
  T r[9], t[3], fx, fy, cx, cy, u_lo, u_hi, v_lo, v_hi;

  Camera(const T* viewmat, const T* k, int64_t width, int64_t height) {
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) r[3 * i + j] = viewmat[4 * i + j];
      t[i] = viewmat[4 * i + 3];
    }
    fx = k[0];
    fy = k[4];
    cx = k[2];
    cy = k[5];
    const T margin = kFrustumMargin;
    const T tan_fovx = T(0.5) * T(width) / fx, tan_fovy = T(0.5) * T(height) / fy;
    u_lo = -(cx / fx + margin * tan_fovx);
    u_hi = (T(width) - cx) / fx + margin * tan_fovx;
    v_lo = -(cy / fy + margin * tan_fovy);
    v_hi = (T(height) - cy) / fy + margin * tan_fovy;
  }
};

struct Settings {
  int64_t width, height;
  double near_plane, far_plane, eps2d;
};

// What one Gaussian is in one camera: every intermediate the backward needs.
template <typename T>
struct PairProjection {
  T x, y, z;                  // camera-space centre
  T rx, ry;                   // x/z and y/z
  bool u_free, v_free;        // the frustum clamp passed x/z (y/z) through
  T u, v;                     // the clamped ratios the Jacobian uses
  T jr[2][3];                 // J·R
  T m[2][3];                  // rows of M = J·R·F; the 2D covariance is M·Mᵀ + eps2d·I
  T a, b, c, det;             // 2D covariance (a, b; b, c) and its determinant
  T mx, my;                   // pixel coordinates of the centre
  bool visible;
  int32_t radius[2], box[4];  // per-axis radius; inclusive pixel box (x0, x1, y0, y1)
};

template <typename T>
T dot3(const T* p, const T* q) {
  return p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
}

// Projects mean / factor F = R·S of one Gaussian whose box spans `mult` σ into `cam`.
template <typename T>
PairProjection<T> project_pair(const Camera<T>& cam, const T* mean, const T* f, T mult,
                               const Settings& s) {
  PairProjection<T> p{};
  p.x = dot3(cam.r + 0, mean) + cam.t[0];
  p.y = dot3(cam.r + 3, mean) + cam.t[1];
  p.z = dot3(cam.r + 6, mean) + cam.t[2];
  const bool in_depth = p.z >= T(s.near_plane) && p.z <= T(s.far_plane);
  if (!in_depth) return p;
  const T z = p.z;
  const T limit = z * T(kMaxRatio);
  if (!(std::abs(p.x) < limit && std::abs(p.y) < limit)) return p;
  p.rx = p.x / z;
  p.ry = p.y / z;
  p.u_free = p.rx >= cam.u_lo && p.rx <= cam.u_hi;
  p.v_free = p.ry >= cam.v_lo && p.ry <= cam.v_hi;
  p.u = std::min(std::max(p.rx, cam.u_lo), cam.u_hi);
  p.v = std::min(std::max(p.ry, cam.v_lo), cam.v_hi);
  const T j00 = cam.fx / z, j02 = -cam.fx * p.u / z;
  const T j11 = cam.fy / z, j12 = -cam.fy * p.v / z;
  for (int i = 0; i < 3; ++i) {
    p.jr[0][i] = j00 * cam.r[i] + j02 * cam.r[6 + i];
    p.jr[1][i] = j11 * cam.r[3 + i] + j12 * cam.r[6 + i];
  }
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < 3; ++j) {
      p.m[k][j] = p.jr[k][0] * f[j] + p.jr[k][1] * f[3 + j] + p.jr[k][2] * f[6 + j];
    }
  }
  const T eps = s.eps2d;
  p.a = dot3(p.m[0], p.m[0]) + eps;
  p.b = dot3(p.m[0], p.m[1]);
  p.c = dot3(p.m[1], p.m[1]) + eps;
  const T max_var = kMaxVarPx;
  if (!(p.a < max_var && p.c < max_var && std::abs(p.b) < max_var)) return p;
  const T w0 = p.m[0][1] * p.m[1][2] - p.m[0][2] * p.m[1][1];
  const T w1 = p.m[0][2] * p.m[1][0] - p.m[0][0] * p.m[1][2];
  const T w2 = p.m[0][0] * p.m[1][1] - p.m[0][1] * p.m[1][0];
  p.det = (w0 * w0 + w1 * w1 + w2 * w2) + eps * (p.a + p.c) - T(s.eps2d * s.eps2d);
  if (!(p.det > std::sqrt(std::numeric_limits<T>::min()))) return p;
  p.mx = cam.fx * p.rx + cam.cx;
  p.my = cam.fy * p.ry + cam.cy;
  if (!(mult > T(0) && std::isfinite(p.mx) && std::isfinite(p.my))) return p;
  const T radius_x = std::ceil(mult * std::sqrt(p.a)), radius_y = std::ceil(mult * std::sqrt(p.c));
  const T x0 = std::max(std::ceil(p.mx - radius_x - T(0.5)), T(0));
  const T x1 = std::min(std::floor(p.mx + radius_x - T(0.5)), T(s.width - 1));
  const T y0 = std::max(std::ceil(p.my - radius_y - T(0.5)), T(0));
  const T y1 = std::min(std::floor(p.my + radius_y - T(0.5)), T(s.height - 1));
  p.visible = x0 <= x1 && y0 <= y1;
  const T top = kMaxPixel;
  p.radius[0] = static_cast<int32_t>(std::min(radius_x, top));
  p.radius[1] = static_cast<int32_t>(std::min(radius_y, top));
  const T corners[4] = {x0, x1, y0, y1};
  for (int i = 0; i < 4; ++i) p.box[i] = static_cast<int32_t>(std::min(std::max(corners[i], T(-1)), top));
  return p;
}

// How many σ from the centre alpha stays >= 1/255 (projection.opacity_sigma_multiplier).
template <typename T>
T sigma_multiplier(T opacity) {
  const T ratio = std::max(opacity / T(kAlphaMin), T(1));
  return std::min(std::sqrt(T(2) * std::log(ratio)), T(kMaxSigmaMult));
}

template <typename T>
std::vector<Camera<T>> cameras_of(const at::Tensor& viewmats, const at::Tensor& ks,
                                  const Settings& s) {
  std::vector<Camera<T>> cams;
  for (int64_t c = 0; c < viewmats.size(0); ++c) {
    cams.emplace_back(viewmats.data_ptr<T>() + 16 * c, ks.data_ptr<T>() + 9 * c, s.width,
                      s.height);
  }
  return cams;
}

// Adds to (gm, gf) the gradient of one visible pair's outputs: means2d (g2d), conics
// (gconic) and depth (gdepth), into the Gaussian's mean and factor.
template <typename T>
void pair_backward(const Camera<T>& cam, const PairProjection<T>& p, const T* f,
                   const Settings& s, const T* g2d, const T* gconic, T gdepth, T* gmean,
                   T* gf) {
  const T eps = s.eps2d, z = p.z;
  // conics = (c, -b, a) / det
  const T det2 = p.det * p.det;
  const T gdet = -(gconic[0] * p.c - gconic[1] * p.b + gconic[2] * p.a) / det2;
  const T ga = gconic[2] / p.det + eps * gdet;
  const T gb = -gconic[1] / p.det;
  const T gc = gconic[0] / p.det + eps * gdet;
  // a = m0·m0 + eps, b = m0·m1, c = m1·m1 + eps, det = |m0 × m1|² + eps·(a + c) − eps²
  const T* m0 = p.m[0];
  const T* m1 = p.m[1];
  const T w[3] = {m0[1] * m1[2] - m0[2] * m1[1], m0[2] * m1[0] - m0[0] * m1[2],
                  m0[0] * m1[1] - m0[1] * m1[0]};
  const T gw[3] = {T(2) * gdet * w[0], T(2) * gdet * w[1], T(2) * gdet * w[2]};
  T gm[2][3];
  for (int j = 0; j < 3; ++j) {
    const int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
    gm[0][j] = T(2) * ga * m0[j] + gb * m1[j] + (m1[j1] * gw[j2] - m1[j2] * gw[j1]);
    gm[1][j] = T(2) * gc * m1[j] + gb * m0[j] + (gw[j1] * m0[j2] - gw[j2] * m0[j1]);
  }
  // M = (J·R)·F
  T gjr[2][3];
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) {
      gjr[k][i] = gm[k][0] * f[3 * i] + gm[k][1] * f[3 * i + 1] + gm[k][2] * f[3 * i + 2];
    }
  }
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) gf[3 * i + j] += p.jr[0][i] * gm[0][j] + p.jr[1][i] * gm[1][j];
  }
  // J·R with J = (fx/z, 0, −fx·u/z; 0, fy/z, −fy·v/z)
  const T gj00 = dot3(gjr[0], cam.r + 0), gj02 = dot3(gjr[0], cam.r + 6);
  const T gj11 = dot3(gjr[1], cam.r + 3), gj12 = dot3(gjr[1], cam.r + 6);
  const T z2 = z * z;
  T gz = gdepth - gj00 * cam.fx / z2 - gj02 * (-cam.fx * p.u) / z2 - gj11 * cam.fy / z2 -
         gj12 * (-cam.fy * p.v) / z2;
  T grx = g2d[0] * cam.fx, gry = g2d[1] * cam.fy;
  if (p.u_free) grx += gj02 / z * -cam.fx;
  if (p.v_free) gry += gj12 / z * -cam.fy;
  // rx = x/z, ry = y/z
  const T gx = grx / z, gy = gry / z;
  gz = gz - grx * p.x / z2 - gry * p.y / z2;
  // (x, y, z) = R·mean + t
  for (int j = 0; j < 3; ++j) gmean[j] += cam.r[j] * gx + cam.r[3 + j] * gy + cam.r[6 + j] * gz;
}

void check_inputs(const at::Tensor& means, const at::Tensor& factors,
                  const at::Tensor& opacities, const at::Tensor& viewmats, const at::Tensor& ks) {
  const auto dtype = means.scalar_type();
  for (const at::Tensor* t : {&means, &factors, &opacities, &viewmats, &ks}) {
    TORCH_CHECK(t->device().is_cpu() && t->is_contiguous() && t->scalar_type() == dtype,
                "projection inputs must be contiguous CPU tensors of one dtype");
  }
  const int64_t n = means.size(0);
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "means must be [N,3]");
  TORCH_CHECK(factors.dim() == 3 && factors.size(0) == n && factors.size(1) == 3 &&
                  factors.size(2) == 3,
              "factors must be [N,3,3]");
  TORCH_CHECK(opacities.dim() == 1 && opacities.size(0) == n, "opacities must be [N]");
  TORCH_CHECK(viewmats.dim() == 3 && viewmats.size(1) == 4 && viewmats.size(2) == 4,
              "viewmats must be [C,4,4]");
  TORCH_CHECK(ks.dim() == 3 && ks.size(0) == viewmats.size(0) && ks.size(1) == 3 &&
                  ks.size(2) == 3,
              "Ks must be [C,3,3]");
}

constexpr int64_t kGrain = 256;

// Calls visit(i, c, row, pair) for every visible (camera c, Gaussian i) pair, row = c·N + i;
// one Gaussian per task with its cameras in order, so a visit may accumulate into row i.
template <typename T, typename Visit>
void for_each_visible_pair(const std::vector<Camera<T>>& cam, const T* mean, const T* f,
                           const T* opacity, int64_t n, const Settings& s, const Visit& visit) {
  const int64_t cams = static_cast<int64_t>(cam.size());
  at::parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const T mult = sigma_multiplier(opacity[i]);
      for (int64_t c = 0; c < cams; ++c) {
        const auto p = project_pair(cam[c], mean + 3 * i, f + 9 * i, mult, s);
        if (p.visible) visit(i, c, c * n + i, p);
      }
    }
  });
}

}  // namespace

std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& factors,
                                        const at::Tensor& opacities, const at::Tensor& viewmats,
                                        const at::Tensor& ks, int64_t width, int64_t height,
                                        double near_plane, double far_plane, double eps2d) {
  check_inputs(means, factors, opacities, viewmats, ks);
  const int64_t cams = viewmats.size(0), n = means.size(0);
  const auto float_options = means.options();
  at::Tensor means2d = at::zeros({cams, n, 2}, float_options);
  at::Tensor conics = at::zeros({cams, n, 3}, float_options);
  at::Tensor depths = at::zeros({cams, n}, float_options);
  at::Tensor radii = at::zeros({cams, n, 2}, float_options.dtype(at::kInt));
  at::Tensor visible = at::zeros({cams, n}, float_options.dtype(at::kBool));
  at::Tensor bounds = at::zeros({cams, n, 4}, float_options.dtype(at::kInt));
  const Settings s{width, height, near_plane, far_plane, eps2d};
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_forward", [&] {
    using T = scalar_t;
    const auto cam = cameras_of<T>(viewmats, ks, s);
    const T* mean = means.data_ptr<T>();
    const T* f = factors.data_ptr<T>();
    const T* opacity = opacities.data_ptr<T>();
    T* out2d = means2d.data_ptr<T>();
    T* out_conic = conics.data_ptr<T>();
    T* out_depth = depths.data_ptr<T>();
    int32_t* out_radius = radii.data_ptr<int32_t>();
    bool* out_visible = visible.data_ptr<bool>();
    int32_t* out_box = bounds.data_ptr<int32_t>();
    for_each_visible_pair(cam, mean, f, opacity, n, s, [&](int64_t, int64_t, int64_t row,
                                                           const PairProjection<T>& p) {
      out2d[2 * row] = p.mx;
      out2d[2 * row + 1] = p.my;
      out_conic[3 * row] = p.c / p.det;
      out_conic[3 * row + 1] = -p.b / p.det;
      out_conic[3 * row + 2] = p.a / p.det;
      out_depth[row] = p.z;
      out_radius[2 * row] = p.radius[0];
      out_radius[2 * row + 1] = p.radius[1];
      out_visible[row] = true;
      for (int k = 0; k < 4; ++k) out_box[4 * row + k] = p.box[k];
    });
  });
  return {means2d, conics, depths, radii, visible, bounds};
}

std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& factors,
                                         const at::Tensor& opacities,
                                         const at::Tensor& viewmats, const at::Tensor& ks,
                                         int64_t width, int64_t height, double near_plane,
                                         double far_plane, double eps2d,
                                         const at::Tensor& grad_means2d,
                                         const at::Tensor& grad_conics,
                                         const at::Tensor& grad_depths) {
  check_inputs(means, factors, opacities, viewmats, ks);
  const int64_t cams = viewmats.size(0), n = means.size(0);
  TORCH_CHECK(grad_means2d.is_contiguous() && grad_means2d.numel() == cams * n * 2 &&
                  grad_conics.is_contiguous() && grad_conics.numel() == cams * n * 3 &&
                  grad_depths.is_contiguous() && grad_depths.numel() == cams * n,
              "projection gradients must be contiguous [C,N,2], [C,N,3], [C,N]");
  at::Tensor grad_means = at::zeros_like(means);
  at::Tensor grad_factors = at::zeros_like(factors);
  const Settings s{width, height, near_plane, far_plane, eps2d};
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_backward", [&] {
    using T = scalar_t;
    const auto cam = cameras_of<T>(viewmats, ks, s);
    const T* mean = means.data_ptr<T>();
    const T* f = factors.data_ptr<T>();
    const T* opacity = opacities.data_ptr<T>();
    const T* g2d = grad_means2d.data_ptr<T>();
    const T* gconic = grad_conics.data_ptr<T>();
    const T* gdepth = grad_depths.data_ptr<T>();
    T* gmean = grad_means.data_ptr<T>();
    T* gf = grad_factors.data_ptr<T>();
    for_each_visible_pair(cam, mean, f, opacity, n, s, [&](int64_t i, int64_t c, int64_t row,
                                                           const PairProjection<T>& p) {
      pair_backward(cam[c], p, f + 9 * i, s, g2d + 2 * row, gconic + 3 * row, gdepth[row],
                    gmean + 3 * i, gf + 9 * i);
    });
  });
  return {grad_means, grad_factors};
}

}  // namespace relaygs
