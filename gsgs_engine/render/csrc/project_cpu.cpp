// gsgs compiled projection: EWA splatting of 3D Gaussians (eq. 2) and SH colour, forward and backward.
//
// Semantics are those of gsgs_engine/render/project.py (the pure-torch oracle): the same culling
// (near/far, non-finite), frustum clamp of tx/tz and ty/tz at 1.3x the image half-extent, low-pass
// dilation of 0.3 px^2, determinant from the squared 2x2 minors of U = J W R S (Cauchy-Binet, no
// cancellation for needles), radius from the largest eigenvalue in double, and colour = SH + 0.5
// clamped at 0 along normalise(mean - camera centre). Gradient masks follow torch's autograd of that
// code: clamp/clamp_min pass the gradient where the input lies inside the closed range.
//
// One pass per Gaussian does projection and SH together (forward), and one pass maps the screen-space
// gradients (means2d, conic, colour, depth) back to means, quaternions, scales and SH coefficients
// (backward). Gaussians are independent, so the work is split over ATen's threads with no reduction and
// the result does not depend on the thread count. Culled Gaussians (radius 0) get exactly zero gradient.
// Templated on the scalar type: float32 is what training runs; float64 lets the tests check the
// hand-written derivatives against autograd of project.py to ~1e-12. The arithmetic is written once over
// a lane policy (project_lanes.h): float32 takes eight Gaussians at a time in vector lanes (and one at a
// time for the tail), float64 one at a time; the eight-lane results equal the one-lane ones bit for bit
// (tested), so the result does not depend on where a thread's share starts either.
// SH coefficients come in one tensor [N, K, 3] or in two, a head [N, K0, 3] and the rest [N, R, 3] (coefficient b is
// head[b] for b < K0, else rest[b - K0]): the trainer passes its DC and higher-band parameters as they are, so no
// concatenated copy is made for every render and no slice of its gradient is scattered back (both forms compute
// the same values; the gradient comes back in the same two parts).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include "hot.h"
#include "project_lanes.h"

#include "phase_timer.h"

#include <algorithm>
#include <atomic>
#include <type_traits>
#include <cmath>
#include <cstdint>
#include <tuple>

namespace {

constexpr double kLowPass = 0.3;     // project.LOW_PASS_DILATION
constexpr double kFrustumSlack = 1.3;  // project.FRUSTUM_SLACK
constexpr double kQuatEps = 1e-12;   // project.QUAT_EPS
constexpr double kDirEps = 1e-24;    // project.view_colors
constexpr double kMaxRadius = 1073741824.0;  // project.MAX_RADIUS = 2^30

// The SH coefficients of every Gaussian: `n_head` of them per channel in `head`, then `n_rest` in `rest` (nullptr
// when n_rest is 0); both [N, n, 3] row-major.
template <typename S>
struct ShIn {
  const S* head;
  int64_t n_head;
  const S* rest;
  int64_t n_rest;
};

// Their gradients, laid out as the inputs.
template <typename S>
struct ShOut {
  S* head;
  S* rest;
};

// sh.py's constants.
constexpr double SH_C0 = 0.28209479177387814;
constexpr double SH_C1 = 0.4886025119029199;
constexpr double SH_C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                             0.5462742152960396};
constexpr double SH_C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                             -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

// The camera in the scalar type the torch code uses (R, t, centre cast to it; scalars as torch casts
// a Python float multiplying a tensor).
template <typename S>
struct Cam {
  S R[9], t[3], centre[3];
  S fx, fy, cx, cy;
  S near_, far_;
  S lim_left, lim_right, lim_top, lim_bottom;
  double fx_d, fy_d, cx_d, cy_d;
  int width, height;
};

template <typename S>
Cam<S> make_cam(const at::Tensor& cam, double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                double near_, double far_) {
  TORCH_CHECK(cam.scalar_type() == at::kDouble && cam.is_contiguous() && cam.numel() == 15,
              "project_cpu: camera must be a contiguous float64 tensor [15] (R row-major, t, centre)");
  const double* c = cam.data_ptr<double>();
  Cam<S> k;
  for (int i = 0; i < 9; ++i) k.R[i] = static_cast<S>(c[i]);
  for (int i = 0; i < 3; ++i) k.t[i] = static_cast<S>(c[9 + i]);
  for (int i = 0; i < 3; ++i) k.centre[i] = static_cast<S>(c[12 + i]);
  k.fx = static_cast<S>(fx);
  k.fy = static_cast<S>(fy);
  k.cx = static_cast<S>(cx);
  k.cy = static_cast<S>(cy);
  k.near_ = static_cast<S>(near_);
  k.far_ = static_cast<S>(far_);
  k.lim_left = static_cast<S>(kFrustumSlack * cx / fx);
  k.lim_right = static_cast<S>(kFrustumSlack * (static_cast<double>(width) - cx) / fx);
  k.lim_top = static_cast<S>(kFrustumSlack * cy / fy);
  k.lim_bottom = static_cast<S>(kFrustumSlack * (static_cast<double>(height) - cy) / fy);
  k.fx_d = fx;
  k.fy_d = fy;
  k.cx_d = cx;
  k.cy_d = cy;
  k.width = static_cast<int>(width);
  k.height = static_cast<int>(height);
  return k;
}

using gsgs_lanes::Eight;
using gsgs_lanes::One;

// 1 / sqrt(max(v, eps)).
template <typename L>
GSGS_LANE_INLINE typename L::T rsqrt_clamped(typename L::T v, typename L::S eps) {
  return typename L::S(1) / L::sqrt(L::max(v, L::splat(eps)));
}

// Rotation matrix (row-major) of a unit quaternion (w, x, y, z), as project.quat_to_rotmat.
template <typename L>
GSGS_LANE_INLINE void rotmat(typename L::T w, typename L::T x, typename L::T y, typename L::T z, typename L::T* R) {
  using S = typename L::S;
  R[0] = S(1) - S(2) * (y * y + z * z);
  R[1] = S(2) * (x * y - w * z);
  R[2] = S(2) * (x * z + w * y);
  R[3] = S(2) * (x * y + w * z);
  R[4] = S(1) - S(2) * (x * x + z * z);
  R[5] = S(2) * (y * z - w * x);
  R[6] = S(2) * (x * z - w * y);
  R[7] = S(2) * (y * z + w * x);
  R[8] = S(1) - S(2) * (x * x + y * y);
}

// SH basis values (sh.py's eval_sh, term by term) along a unit direction; returns the count used.
template <typename L>
GSGS_LANE_INLINE int sh_basis(int degree, typename L::T x, typename L::T y, typename L::T z, typename L::T* b) {
  using S = typename L::S;
  b[0] = L::splat(static_cast<S>(SH_C0));
  if (degree == 0) return 1;
  const S c1 = static_cast<S>(SH_C1);
  b[1] = -c1 * y;
  b[2] = c1 * z;
  b[3] = -c1 * x;
  if (degree == 1) return 4;
  const typename L::T xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  b[4] = static_cast<S>(SH_C2[0]) * xy;
  b[5] = static_cast<S>(SH_C2[1]) * yz;
  b[6] = static_cast<S>(SH_C2[2]) * (S(2) * zz - xx - yy);
  b[7] = static_cast<S>(SH_C2[3]) * xz;
  b[8] = static_cast<S>(SH_C2[4]) * (xx - yy);
  if (degree == 2) return 9;
  b[9] = static_cast<S>(SH_C3[0]) * y * (S(3) * xx - yy);
  b[10] = static_cast<S>(SH_C3[1]) * xy * z;
  b[11] = static_cast<S>(SH_C3[2]) * y * (S(4) * zz - xx - yy);
  b[12] = static_cast<S>(SH_C3[3]) * z * (S(2) * zz - S(3) * xx - S(3) * yy);
  b[13] = static_cast<S>(SH_C3[4]) * x * (S(4) * zz - xx - yy);
  b[14] = static_cast<S>(SH_C3[5]) * z * (xx - yy);
  b[15] = static_cast<S>(SH_C3[6]) * x * (xx - S(3) * yy);
  return 16;
}

// d(basis_k)/d(x, y, z) for k < count, as rows [k][3].
template <typename L>
GSGS_LANE_INLINE void sh_basis_grad(int degree, typename L::T x, typename L::T y, typename L::T z,
                                    typename L::T (*d)[3]) {
  using S = typename L::S;
  const typename L::T zero = L::splat(S(0));
  for (int k = 0; k < 16; ++k) d[k][0] = d[k][1] = d[k][2] = zero;
  if (degree == 0) return;
  const S c1 = static_cast<S>(SH_C1);
  d[1][1] = L::splat(-c1);
  d[2][2] = L::splat(c1);
  d[3][0] = L::splat(-c1);
  if (degree == 1) return;
  const typename L::T xx = x * x, yy = y * y, zz = z * z;
  const S a0 = static_cast<S>(SH_C2[0]), a1 = static_cast<S>(SH_C2[1]), a2 = static_cast<S>(SH_C2[2]),
          a3 = static_cast<S>(SH_C2[3]), a4 = static_cast<S>(SH_C2[4]);
  d[4][0] = a0 * y, d[4][1] = a0 * x;
  d[5][1] = a1 * z, d[5][2] = a1 * y;
  d[6][0] = -2 * a2 * x, d[6][1] = -2 * a2 * y, d[6][2] = 4 * a2 * z;
  d[7][0] = a3 * z, d[7][2] = a3 * x;
  d[8][0] = 2 * a4 * x, d[8][1] = -2 * a4 * y;
  if (degree == 2) return;
  const S b0 = static_cast<S>(SH_C3[0]), b1 = static_cast<S>(SH_C3[1]), b2 = static_cast<S>(SH_C3[2]),
          b3 = static_cast<S>(SH_C3[3]), b4 = static_cast<S>(SH_C3[4]), b5 = static_cast<S>(SH_C3[5]),
          b6 = static_cast<S>(SH_C3[6]);
  d[9][0] = b0 * 6 * x * y, d[9][1] = b0 * (S(3) * xx - S(3) * yy);
  d[10][0] = b1 * y * z, d[10][1] = b1 * x * z, d[10][2] = b1 * x * y;
  d[11][0] = b2 * (S(-2) * x * y), d[11][1] = b2 * (S(4) * zz - xx - S(3) * yy), d[11][2] = b2 * 8 * y * z;
  d[12][0] = b3 * (S(-6) * x * z), d[12][1] = b3 * (S(-6) * y * z), d[12][2] = b3 * (S(6) * zz - S(3) * xx - S(3) * yy);
  d[13][0] = b4 * (S(4) * zz - S(3) * xx - yy), d[13][1] = b4 * (S(-2) * x * y), d[13][2] = b4 * 8 * x * z;
  d[14][0] = b5 * 2 * x * z, d[14][1] = b5 * (S(-2) * y * z), d[14][2] = b5 * (xx - yy);
  d[15][0] = b6 * (S(3) * xx - S(3) * yy), d[15][1] = b6 * (S(-6) * x * y);
}

// Everything of one Gaussian's projection (one per lane) the backward needs again (recomputed there, not stored).
template <typename L>
struct Proj {
  using T = typename L::T;
  T m[3], q[4], s[3];  // the inputs: mean, quaternion, scales
  typename L::M in_range, ok;
  T x, y, z;          // camera-space mean (safe point (0, 0, 1) when out of range)
  T txtz, tytz;       // unclamped x/z, y/z
  T J[6];             // 2x3
  T JW[6];            // J @ W, 2x3
  T Rq[9];            // rotation of the normalised quaternion
  T qn[4], q_inv;     // normalised quaternion and 1 / |q| (clamped)
  T M[9];             // Rq * diag(scales)
  T U[6];             // JW @ M
  T a, b, c, det;     // undilated covariance entries and the dilated determinant
  T a_s, b_s, c_s, det_s;
};

// The clamped tx/tz and ty/tz of the EWA Jacobian.
template <typename L>
GSGS_LANE_INLINE typename L::T clamp_x(const Cam<typename L::S>& k, typename L::T txtz) {
  return L::min(L::max(txtz, L::splat(-k.lim_left)), L::splat(k.lim_right));
}
template <typename L>
GSGS_LANE_INLINE typename L::T clamp_y(const Cam<typename L::S>& k, typename L::T tytz) {
  return L::min(L::max(tytz, L::splat(-k.lim_top)), L::splat(k.lim_bottom));
}

// Gaussians g .. g + L::kWidth - 1 of the means [N, 3], quaternions [N, 4] and scales [N, 3].
template <typename L>
GSGS_LANE_INLINE void project_one(const Cam<typename L::S>& k, const typename L::S* mp, const typename L::S* qp,
                                  const typename L::S* sp, int64_t g, Proj<L>& p) {
  using S = typename L::S;
  using T = typename L::T;
  for (int i = 0; i < 3; ++i) p.m[i] = L::load(mp, 3, g, i);
  for (int i = 0; i < 4; ++i) p.q[i] = L::load(qp, 4, g, i);
  for (int i = 0; i < 3; ++i) p.s[i] = L::load(sp, 3, g, i);
  const T *m = p.m, *q = p.q, *s = p.s;
  const S* R = k.R;
  T pc[3];
  for (int r = 0; r < 3; ++r) pc[r] = R[3 * r] * m[0] + R[3 * r + 1] * m[1] + R[3 * r + 2] * m[2] + k.t[r];
  p.in_range = L::both(L::both(L::both(pc[2] > L::splat(k.near_), pc[2] < L::splat(k.far_)),
                               L::both(L::finite(pc[0]), L::finite(pc[1]))), L::finite(pc[2]));
  p.x = L::sel(p.in_range, pc[0], L::splat(S(0)));
  p.y = L::sel(p.in_range, pc[1], L::splat(S(0)));
  p.z = L::sel(p.in_range, pc[2], L::splat(S(1)));
  const T x = p.x, y = p.y, z = p.z;
  p.txtz = x / z;
  p.tytz = y / z;
  const T cxz = clamp_x<L>(k, p.txtz);
  const T cyz = clamp_y<L>(k, p.tytz);
  p.J[0] = k.fx / z;
  p.J[1] = L::splat(S(0));
  p.J[2] = -k.fx * cxz / z;
  p.J[3] = L::splat(S(0));
  p.J[4] = k.fy / z;
  p.J[5] = -k.fy * cyz / z;
  for (int r = 0; r < 2; ++r)
    for (int col = 0; col < 3; ++col)
      p.JW[3 * r + col] = p.J[3 * r] * R[col] + p.J[3 * r + 1] * R[3 + col] + p.J[3 * r + 2] * R[6 + col];

  const T qq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
  p.q_inv = rsqrt_clamped<L>(qq, static_cast<S>(kQuatEps));
  for (int i = 0; i < 4; ++i) p.qn[i] = q[i] * p.q_inv;
  rotmat<L>(p.qn[0], p.qn[1], p.qn[2], p.qn[3], p.Rq);
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col) p.M[3 * r + col] = p.Rq[3 * r + col] * s[col];
  for (int r = 0; r < 2; ++r)
    for (int col = 0; col < 3; ++col)
      p.U[3 * r + col] = p.JW[3 * r] * p.M[col] + p.JW[3 * r + 1] * p.M[3 + col] + p.JW[3 * r + 2] * p.M[6 + col];
  const T* U = p.U;
  p.a = U[0] * U[0] + U[1] * U[1] + U[2] * U[2];
  p.b = U[0] * U[3] + U[1] * U[4] + U[2] * U[5];
  p.c = U[3] * U[3] + U[4] * U[4] + U[5] * U[5];
  const T m01 = U[0] * U[4] - U[1] * U[3];
  const T m02 = U[0] * U[5] - U[2] * U[3];
  const T m12 = U[1] * U[5] - U[2] * U[4];
  const S lp = static_cast<S>(kLowPass);
  p.det = m01 * m01 + m02 * m02 + m12 * m12 + lp * (p.a + p.c) + static_cast<S>(kLowPass * kLowPass);
  p.ok = L::both(L::both(p.in_range, p.det > L::splat(S(0))), L::finite(p.det));
  p.det_s = L::sel(p.ok, p.det, L::splat(S(1)));
  p.a_s = L::sel(p.ok, p.a + lp, L::splat(S(1)));
  p.b_s = L::sel(p.ok, p.b, L::splat(S(0)));
  p.c_s = L::sel(p.ok, p.c + lp, L::splat(S(1)));
}

template <typename S>
void check_tensor(const at::Tensor& t, const char* name, int64_t n, std::initializer_list<int64_t> tail) {
  TORCH_CHECK(t.device().is_cpu(), "project_cpu: ", name, " must be a CPU tensor");
  TORCH_CHECK(t.scalar_type() == c10::CppTypeToScalarType<S>::value, "project_cpu: ", name, " has dtype ",
              t.scalar_type(), ", expected ", c10::CppTypeToScalarType<S>::value);
  TORCH_CHECK(t.is_contiguous(), "project_cpu: ", name, " must be contiguous");
  TORCH_CHECK(t.dim() == 1 + static_cast<int64_t>(tail.size()) && t.size(0) == n, "project_cpu: ", name,
              " has shape ", t.sizes());
  int d = 1;
  for (int64_t v : tail) {
    if (v >= 0) TORCH_CHECK(t.size(d) == v, "project_cpu: ", name, " has shape ", t.sizes());
    ++d;
  }
}

template <typename S>
ShIn<S> check_all(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales, const at::Tensor& sh,
                  const c10::optional<at::Tensor>& sh_rest, int64_t sh_degree) {
  const int64_t n = means.size(0);
  check_tensor<S>(means, "means", n, {3});
  check_tensor<S>(quats, "quats", n, {4});
  check_tensor<S>(scales, "scales", n, {3});
  check_tensor<S>(sh, "sh", n, {-1, 3});
  TORCH_CHECK(sh.size(1) >= 1, "project_cpu: sh needs at least the DC coefficient, got ", sh.sizes());
  ShIn<S> h{sh.data_ptr<S>(), sh.size(1), nullptr, 0};
  if (sh_rest.has_value()) {
    check_tensor<S>(*sh_rest, "sh_rest", n, {-1, 3});
    h.n_rest = sh_rest->size(1);
    if (h.n_rest > 0) h.rest = sh_rest->data_ptr<S>();
  }
  TORCH_CHECK(sh_degree >= 0 && sh_degree <= 3, "project_cpu: sh_degree must be 0-3, got ", sh_degree);
  TORCH_CHECK(h.n_head + h.n_rest >= (sh_degree + 1) * (sh_degree + 1), "project_cpu: sh has ", h.n_head + h.n_rest,
              " coefficients per channel, degree ", sh_degree, " needs ", (sh_degree + 1) * (sh_degree + 1));
  return h;
}

// Whether float32 projections take eight Gaussians at a time (1, the default) or one (0: the one-lane code the
// eight-lane code must equal bit for bit; set by tests through project_lane_width).
std::atomic<int> g_eight_lanes{1};

// The first `nb` coefficients of Gaussians g .. g + L::kWidth - 1, [b][ch], from the head and then the rest (out holds
// 3 nb values and room for a last whole run of 8 fields, as L::load_fields writes).
template <typename L>
GSGS_LANE_INLINE void load_coeffs(const ShIn<typename L::S>& h, int64_t g, int nb, typename L::T* out) {
  const int from_head = static_cast<int>(std::min<int64_t>(nb, h.n_head));
  L::load_fields(h.head, h.n_head * 3, g, 3 * from_head, out);
  if (nb > from_head) L::load_fields(h.rest, h.n_rest * 3, g, 3 * (nb - from_head), out + 3 * from_head);
}

// Projection and colour of Gaussians g .. g + L::kWidth - 1.
template <typename L>
GSGS_LANE_INLINE void forward_lanes(const Cam<typename L::S>& k, const typename L::S* mp, const typename L::S* qp,
                                    const typename L::S* sp, const ShIn<typename L::S>& h,
                                    int64_t sh_degree, typename L::S* o_m, typename L::S* o_k, typename L::S* o_d,
                                    typename L::S* o_c, int32_t* o_r, int64_t g) {
  using S = typename L::S;
  using T = typename L::T;
  Proj<L> p;
  project_one<L>(k, mp, qp, sp, g, p);
  const T *m = p.m, *q = p.q, *s = p.s;
  L::store(o_k, 3, g, 0, p.c_s / p.det_s);
  L::store(o_k, 3, g, 1, -p.b_s / p.det_s);
  L::store(o_k, 3, g, 2, p.a_s / p.det_s);
  const T mx = k.fx * p.x / p.z + k.cx;
  const T my = k.fy * p.y / p.z + k.cy;
  L::store(o_m, 2, g, 0, mx);
  L::store(o_m, 2, g, 1, my);
  L::store(o_d, 1, g, 0, p.z);
  // Radius from the largest eigenvalue, in double (no gradient), one Gaussian at a time.
  for (int i = 0; i < L::kWidth; ++i) {
    const double a64 = L::lane(p.a_s, i), c64 = L::lane(p.c_s, i), det64 = L::lane(p.det_s, i);
    const double mid = 0.5 * (a64 + c64);
    const double lam = mid + std::sqrt(std::max(mid * mid - det64, 0.0));
    const double radius = std::ceil(3.0 * std::sqrt(std::max(lam, 0.0)));
    const double mx64 = L::lane(mx, i), my64 = L::lane(my, i);
    const bool on_screen = mx64 + radius > 0 && mx64 - radius < k.width && my64 + radius > 0 &&
                           my64 - radius < k.height;
    const bool visible = L::lane(p.ok, i) && on_screen && std::isfinite(radius);
    o_r[g + i] = visible ? static_cast<int32_t>(std::min(std::max(radius, 1.0), kMaxRadius)) : 0;
  }

  // Colour along the view direction.
  const T dir[3] = {m[0] - k.centre[0], m[1] - k.centre[1], m[2] - k.centre[2]};
  const T inv = rsqrt_clamped<L>(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2], static_cast<S>(kDirEps));
  T basis[16];
  const int nb = sh_basis<L>(static_cast<int>(sh_degree), dir[0] * inv, dir[1] * inv, dir[2] * inv, basis);
  T coeffs[16 * 3 + 8];  // the used coefficients, [b][ch] (room for a last whole run of 8 fields)
  load_coeffs<L>(h, g, nb, coeffs);
  for (int ch = 0; ch < 3; ++ch) {
    T v = L::splat(S(0));
    for (int b = 0; b < nb; ++b) v += basis[b] * coeffs[3 * b + ch];
    v += S(0.5);
    L::store(o_c, 3, g, ch, L::sel(v >= L::splat(S(0)), v, L::splat(S(0))));
  }
}

// Projection and colour of Gaussians [g0, g1) (one thread's share).
template <typename S>
GSGS_HOT void forward_range(const Cam<S>& k, const S* mp, const S* qp, const S* sp, const ShIn<S>& h,
                            int64_t sh_degree, S* o_m, S* o_k, S* o_d, S* o_c, int32_t* o_r, int64_t g0, int64_t g1) {
  int64_t g = g0;
  if constexpr (std::is_same_v<S, float>) {
    if (g_eight_lanes.load(std::memory_order_relaxed))
      for (; g + Eight::kWidth <= g1; g += Eight::kWidth)
        forward_lanes<Eight>(k, mp, qp, sp, h, sh_degree, o_m, o_k, o_d, o_c, o_r, g);
  }
  for (; g < g1; ++g) forward_lanes<One<S>>(k, mp, qp, sp, h, sh_degree, o_m, o_k, o_d, o_c, o_r, g);
}

// Gradients of Gaussians g .. g + L::kWidth - 1. A culled Gaussian (radius 0: the rasteriser ignored it) gets
// exactly zero; a branch of the one-lane code not taken by a lane is computed and selected away.
template <typename L>
GSGS_LANE_INLINE void backward_lanes(const Cam<typename L::S>& k, const typename L::S* mp, const typename L::S* qp,
                                     const typename L::S* sp, const ShIn<typename L::S>& h, int deg,
                                     const int32_t* rp, const typename L::S* gm, const typename L::S* gk,
                                     const typename L::S* gd, const typename L::S* gc, typename L::S* dm_p,
                                     typename L::S* dq_p, typename L::S* ds_p, const ShOut<typename L::S>& dh,
                                     int64_t g) {
  using S = typename L::S;
  using T = typename L::T;
  using Mask = typename L::M;
  const T zero = L::splat(S(0));
  Mask drawn;
  if constexpr (L::kWidth == 1) {
    drawn = rp[g] > 0;
  } else {
    for (int i = 0; i < L::kWidth; ++i) drawn[i] = rp[g + i] > 0 ? -1 : 0;
  }
  bool any_drawn = false;
  for (int i = 0; i < L::kWidth; ++i) any_drawn = any_drawn || L::lane(drawn, i);
  if (!any_drawn) {  // nothing reaches these Gaussians' parameters
    for (int i = 0; i < L::kWidth; ++i) {
      std::fill(dh.head + (g + i) * h.n_head * 3, dh.head + (g + i + 1) * h.n_head * 3, S(0));
      if (h.n_rest > 0) std::fill(dh.rest + (g + i) * h.n_rest * 3, dh.rest + (g + i + 1) * h.n_rest * 3, S(0));
      std::fill(dm_p + 3 * (g + i), dm_p + 3 * (g + i + 1), S(0));
      std::fill(dq_p + 4 * (g + i), dq_p + 4 * (g + i + 1), S(0));
      std::fill(ds_p + 3 * (g + i), ds_p + 3 * (g + i + 1), S(0));
    }
    return;
  }
  Proj<L> p;
  project_one<L>(k, mp, qp, sp, g, p);
  const T *m = p.m, *q = p.q, *s = p.s;
  const T x = p.x, y = p.y, z = p.z;

  // --- colour: SH + 0.5, clamp_min(0) --------------------------------------------------
  T dmean[3] = {zero, zero, zero};
  {
    const T v[3] = {m[0] - k.centre[0], m[1] - k.centre[1], m[2] - k.centre[2]};
    const T vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    const T inv = rsqrt_clamped<L>(vv, static_cast<S>(kDirEps));
    const T d[3] = {v[0] * inv, v[1] * inv, v[2] * inv};
    T basis[16];
    const int nb = sh_basis<L>(deg, d[0], d[1], d[2], basis);
    T coeffs[16 * 3 + 8];  // [b][ch], as in the forward
    load_coeffs<L>(h, g, nb, coeffs);
    T dcol[3];
    Mask any = L::none();
    for (int ch = 0; ch < 3; ++ch) {
      T val = zero;
      for (int b = 0; b < nb; ++b) val += basis[b] * coeffs[3 * b + ch];
      val += S(0.5);
      dcol[ch] = L::sel(val >= zero, L::load(gc, 3, g, ch), zero);
      any = L::either(any, dcol[ch] != zero);
    }
    auto d_coeff = [&](int64_t f) {  // field f = 3 b + ch of the coefficients, head and rest together
      return f < 3 * nb ? L::sel(drawn, basis[f / 3] * dcol[f % 3], zero) : zero;
    };
    L::store_fields(dh.head, h.n_head * 3, g, d_coeff);
    if (h.n_rest > 0) L::store_fields(dh.rest, h.n_rest * 3, g, [&](int64_t f) { return d_coeff(f + 3 * h.n_head); });
    if (deg > 0) {
      T db[16][3];
      sh_basis_grad<L>(deg, d[0], d[1], d[2], db);
      T ddir[3] = {zero, zero, zero};
      for (int b = 1; b < nb; ++b) {
        const T w = coeffs[3 * b] * dcol[0] + coeffs[3 * b + 1] * dcol[1] + coeffs[3 * b + 2] * dcol[2];
        for (int i = 0; i < 3; ++i) ddir[i] += w * db[b][i];
      }
      // d = v * rsqrt(max(|v|^2, eps)): dv = inv ddir - inv^3 (ddir . v) v where |v|^2 >= eps
      const T dot = ddir[0] * v[0] + ddir[1] * v[1] + ddir[2] * v[2];
      const T k3 = L::sel(vv >= L::splat(static_cast<S>(kDirEps)), inv * inv * inv * dot, zero);
      for (int i = 0; i < 3; ++i) dmean[i] = L::sel(any, dmean[i] + (inv * ddir[i] - k3 * v[i]), dmean[i]);
    }
  }

  // --- camera-space point: means2d and depth ----------------------------------------------
  T dx = zero, dy = zero, dz = L::load(gd, 1, g, 0);
  {
    const T gmx = L::load(gm, 2, g, 0), gmy = L::load(gm, 2, g, 1);
    dx += gmx * k.fx / z;
    dy += gmy * k.fy / z;
    dz -= (gmx * k.fx * x + gmy * k.fy * y) / (z * z);
  }

  // --- conic (c, -b, a) / det and the dilated determinant (where the projection is ok) --------
  T dU[6] = {zero, zero, zero, zero, zero, zero};
  {
    const T* U = p.U;
    const T k0 = L::load(gk, 3, g, 0), k1 = L::load(gk, 3, g, 1), k2 = L::load(gk, 3, g, 2);
    const T inv_det = S(1) / p.det;
    const T ddet = -(k0 * p.c_s - k1 * p.b_s + k2 * p.a_s) * inv_det * inv_det;
    const S lp = static_cast<S>(kLowPass);
    const T da = k2 * inv_det + lp * ddet;
    const T dc = k0 * inv_det + lp * ddet;
    const T db = -k1 * inv_det;
    const T m01 = U[0] * U[4] - U[1] * U[3];
    const T m02 = U[0] * U[5] - U[2] * U[3];
    const T m12 = U[1] * U[5] - U[2] * U[4];
    const T d01 = S(2) * m01 * ddet, d02 = S(2) * m02 * ddet, d12 = S(2) * m12 * ddet;
    T e[6] = {zero, zero, zero, zero, zero, zero};
    for (int i = 0; i < 3; ++i) {
      e[i] += S(2) * da * U[i] + db * U[3 + i];
      e[3 + i] += S(2) * dc * U[3 + i] + db * U[i];
    }
    e[0] += d01 * U[4] + d02 * U[5];
    e[4] += d01 * U[0] - d12 * U[2];
    e[1] += -d01 * U[3] + d12 * U[5];
    e[3] += -d01 * U[1] - d02 * U[2];
    e[5] += d02 * U[0] + d12 * U[1];
    e[2] += -d02 * U[3] - d12 * U[4];
    for (int i = 0; i < 6; ++i) dU[i] = L::sel(p.ok, e[i], zero);
  }
  // U = JW M: dJW = dU M^T, dM = JW^T dU
  T dJW[6], dM[9];
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c)
      dJW[3 * r + c] = dU[3 * r] * p.M[3 * c] + dU[3 * r + 1] * p.M[3 * c + 1] + dU[3 * r + 2] * p.M[3 * c + 2];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) dM[3 * r + c] = p.JW[r] * dU[c] + p.JW[3 + r] * dU[3 + c];
  // JW = J W: dJ = dJW W^T (only J00, J02, J11, J12 depend on the point)
  const S* R = k.R;
  T dJ[6];
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c)
      dJ[3 * r + c] = dJW[3 * r] * R[3 * c] + dJW[3 * r + 1] * R[3 * c + 1] + dJW[3 * r + 2] * R[3 * c + 2];
  {
    const T cxz = clamp_x<L>(k, p.txtz);
    const T cyz = clamp_y<L>(k, p.tytz);
    const T z2 = z * z;
    dz += -dJ[0] * k.fx / z2 + dJ[2] * k.fx * cxz / z2 - dJ[4] * k.fy / z2 + dJ[5] * k.fy * cyz / z2;
    const T dtx = -dJ[2] * k.fx / z;
    const T dty = -dJ[5] * k.fy / z;
    const Mask inside_x = L::both(p.txtz >= L::splat(-k.lim_left), p.txtz <= L::splat(k.lim_right));
    dx = L::sel(inside_x, dx + dtx / z, dx);
    dz = L::sel(inside_x, dz - dtx * x / z2, dz);
    const Mask inside_y = L::both(p.tytz >= L::splat(-k.lim_top), p.tytz <= L::splat(k.lim_bottom));
    dy = L::sel(inside_y, dy + dty / z, dy);
    dz = L::sel(inside_y, dz - dty * y / z2, dz);
  }
  // p_cam = R m + t
  for (int i = 0; i < 3; ++i)
    dmean[i] = L::sel(p.in_range, dmean[i] + (R[i] * dx + R[3 + i] * dy + R[6 + i] * dz), dmean[i]);
  for (int i = 0; i < 3; ++i) L::store(dm_p, 3, g, i, L::sel(drawn, dmean[i], zero));

  // M = Rq diag(s)
  T dR[9];
  for (int c = 0; c < 3; ++c) {
    const T ds = dM[c] * p.Rq[c] + dM[3 + c] * p.Rq[3 + c] + dM[6 + c] * p.Rq[6 + c];
    L::store(ds_p, 3, g, c, L::sel(drawn, ds, zero));
    for (int r = 0; r < 3; ++r) dR[3 * r + c] = dM[3 * r + c] * s[c];
  }
  // Rq(w, x, y, z) of the normalised quaternion
  const T w = p.qn[0], qx = p.qn[1], qy = p.qn[2], qz = p.qn[3];
  T dqn[4];
  dqn[0] = S(2) * (-qz * dR[1] + qy * dR[2] + qz * dR[3] - qx * dR[5] - qy * dR[6] + qx * dR[7]);
  dqn[1] = S(2) * (qy * dR[1] + qz * dR[2] + qy * dR[3] - S(2) * qx * dR[4] - w * dR[5] + qz * dR[6] + w * dR[7] -
                   S(2) * qx * dR[8]);
  dqn[2] = S(2) * (S(-2) * qy * dR[0] + qx * dR[1] + w * dR[2] + qx * dR[3] + qz * dR[5] - w * dR[6] + qz * dR[7] -
                   S(2) * qy * dR[8]);
  dqn[3] = S(2) * (S(-2) * qz * dR[0] - w * dR[1] + qx * dR[2] + w * dR[3] - S(2) * qz * dR[4] + qy * dR[5] +
                   qx * dR[6] + qy * dR[7]);
  // qn = q rsqrt(max(|q|^2, eps))
  const T qq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
  const T inv = p.q_inv;
  const T dot = dqn[0] * q[0] + dqn[1] * q[1] + dqn[2] * q[2] + dqn[3] * q[3];
  const T k3 = L::sel(qq >= L::splat(static_cast<S>(kQuatEps)), inv * inv * inv * dot, zero);
  for (int i = 0; i < 4; ++i) L::store(dq_p, 4, g, i, L::sel(drawn, inv * dqn[i] - k3 * q[i], zero));
}

// Gradients of Gaussians [g0, g1) (one thread's share).
template <typename S>
GSGS_HOT void backward_range(const Cam<S>& k, const S* mp, const S* qp, const S* sp, const ShIn<S>& h, int deg,
                             const int32_t* rp, const S* gm, const S* gk, const S* gd, const S* gc, S* dm_p,
                             S* dq_p, S* ds_p, const ShOut<S>& dh, int64_t g0, int64_t g1) {
  int64_t g = g0;
  if constexpr (std::is_same_v<S, float>) {
    if (g_eight_lanes.load(std::memory_order_relaxed))
      for (; g + Eight::kWidth <= g1; g += Eight::kWidth)
        backward_lanes<Eight>(k, mp, qp, sp, h, deg, rp, gm, gk, gd, gc, dm_p, dq_p, ds_p, dh, g);
  }
  for (; g < g1; ++g)
    backward_lanes<One<S>>(k, mp, qp, sp, h, deg, rp, gm, gk, gd, gc, dm_p, dq_p, ds_p, dh, g);
}

using ProjectResult = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

template <typename S>
ProjectResult forward_impl(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                           const at::Tensor& sh, const c10::optional<at::Tensor>& sh_rest, const at::Tensor& cam,
                           double fx, double fy, double cx, double cy, int64_t width, int64_t height, double near_,
                           double far_, int64_t sh_degree) {
  gsgs_phase::Lap lap;
  const ShIn<S> h = check_all<S>(means, quats, scales, sh, sh_rest, sh_degree);
  const Cam<S> k = make_cam<S>(cam, fx, fy, cx, cy, width, height, near_, far_);
  const int64_t n = means.size(0);
  const auto opts = means.options();
  at::Tensor means2d = at::empty({n, 2}, opts);
  at::Tensor conics = at::empty({n, 3}, opts);
  at::Tensor depths = at::empty({n}, opts);
  at::Tensor colors = at::empty({n, 3}, opts);
  at::Tensor radii = at::empty({n}, opts.dtype(at::kInt));
  const S* mp = means.data_ptr<S>();
  const S* qp = quats.data_ptr<S>();
  const S* sp = scales.data_ptr<S>();
  S* o_m = means2d.data_ptr<S>();
  S* o_k = conics.data_ptr<S>();
  S* o_d = depths.data_ptr<S>();
  S* o_c = colors.data_ptr<S>();
  int32_t* o_r = radii.data_ptr<int32_t>();
  at::parallel_for(0, n, 1024, [&](int64_t g0, int64_t g1) {
    forward_range(k, mp, qp, sp, h, sh_degree, o_m, o_k, o_d, o_c, o_r, g0, g1);
  });
  lap(gsgs_phase::kProjectForward);
  return {means2d, conics, depths, radii, colors};
}

using ProjectGrads = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

template <typename S>
ProjectGrads backward_impl(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                           const at::Tensor& sh, const c10::optional<at::Tensor>& sh_rest, const at::Tensor& cam,
                           double fx, double fy, double cx, double cy, int64_t width, int64_t height, double near_,
                           double far_, int64_t sh_degree, const at::Tensor& radii, const at::Tensor& g_means2d,
                           const at::Tensor& g_conics, const at::Tensor& g_depths, const at::Tensor& g_colors) {
  gsgs_phase::Lap lap;
  const ShIn<S> h = check_all<S>(means, quats, scales, sh, sh_rest, sh_degree);
  const int64_t n = means.size(0);
  check_tensor<S>(g_means2d, "grad means2d", n, {2});
  check_tensor<S>(g_conics, "grad conics", n, {3});
  check_tensor<S>(g_depths, "grad depths", n, {});
  check_tensor<S>(g_colors, "grad colors", n, {3});
  TORCH_CHECK(radii.scalar_type() == at::kInt && radii.is_contiguous() && radii.numel() == n,
              "project_cpu backward: radii must be int32 [N]");
  const Cam<S> k = make_cam<S>(cam, fx, fy, cx, cy, width, height, near_, far_);
  at::Tensor d_means = at::empty({n, 3}, means.options());
  at::Tensor d_quats = at::empty({n, 4}, means.options());
  at::Tensor d_scales = at::empty({n, 3}, means.options());
  at::Tensor d_sh = at::empty({n, h.n_head, 3}, means.options());
  // the rest's gradient has the rest's shape (every coefficient written: zero past the degree's)
  at::Tensor d_sh_rest = at::empty({n, sh_rest.has_value() ? sh_rest->size(1) : 0, 3}, means.options());
  const S* mp = means.data_ptr<S>();
  const S* qp = quats.data_ptr<S>();
  const S* sp = scales.data_ptr<S>();
  const int32_t* rp = radii.data_ptr<int32_t>();
  const S* gm = g_means2d.data_ptr<S>();
  const S* gk = g_conics.data_ptr<S>();
  const S* gd = g_depths.data_ptr<S>();
  const S* gc = g_colors.data_ptr<S>();
  S* dm_p = d_means.data_ptr<S>();
  S* dq_p = d_quats.data_ptr<S>();
  S* ds_p = d_scales.data_ptr<S>();
  const ShOut<S> dh{d_sh.data_ptr<S>(), h.n_rest > 0 ? d_sh_rest.data_ptr<S>() : nullptr};
  const int deg = static_cast<int>(sh_degree);
  at::parallel_for(0, n, 512, [&](int64_t g0, int64_t g1) {
    backward_range(k, mp, qp, sp, h, deg, rp, gm, gk, gd, gc, dm_p, dq_p, ds_p, dh, g0, g1);
  });
  lap(gsgs_phase::kProjectBackward);
  return {d_means, d_quats, d_scales, d_sh, d_sh_rest};
}

ProjectResult project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                              const at::Tensor& sh, const c10::optional<at::Tensor>& sh_rest, const at::Tensor& cam,
                              double fx, double fy, double cx, double cy, int64_t width, int64_t height, double near_,
                              double far_, int64_t sh_degree) {
  TORCH_CHECK(means.dim() == 2, "project_cpu: means must be [N, 3]");
  TORCH_CHECK(width > 0 && height > 0, "project_cpu: image size must be positive");
  if (means.scalar_type() == at::kDouble)
    return forward_impl<double>(means, quats, scales, sh, sh_rest, cam, fx, fy, cx, cy, width, height, near_, far_,
                                sh_degree);
  return forward_impl<float>(means, quats, scales, sh, sh_rest, cam, fx, fy, cx, cy, width, height, near_, far_,
                             sh_degree);
}

ProjectGrads project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                              const at::Tensor& sh, const c10::optional<at::Tensor>& sh_rest, const at::Tensor& cam,
                              double fx, double fy, double cx, double cy, int64_t width, int64_t height, double near_,
                              double far_, int64_t sh_degree,
                              const at::Tensor& radii, const at::Tensor& g_means2d, const at::Tensor& g_conics,
                              const at::Tensor& g_depths, const at::Tensor& g_colors) {
  TORCH_CHECK(means.dim() == 2, "project_cpu: means must be [N, 3]");
  if (means.scalar_type() == at::kDouble)
    return backward_impl<double>(means, quats, scales, sh, sh_rest, cam, fx, fy, cx, cy, width, height, near_, far_,
                                 sh_degree, radii, g_means2d, g_conics, g_depths, g_colors);
  return backward_impl<float>(means, quats, scales, sh, sh_rest, cam, fx, fy, cx, cy, width, height, near_, far_,
                              sh_degree, radii, g_means2d, g_conics, g_depths, g_colors);
}

// Sets how many float32 Gaussians the projection takes at a time (8, or 1 for the one-lane code); returns the
// previous width. For tests: both widths give the same bits.
int64_t project_lane_width(int64_t width) {
  TORCH_CHECK(width == 1 || width == 8, "project_lane_width: 1 or 8, got ", width);
  return g_eight_lanes.exchange(width == 8 ? 1 : 0) ? 8 : 1;
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(gsgs_raster_cpu, m) {
  m.def("project_lane_width(int width) -> int", &project_lane_width);
  m.def(
      "project_forward(Tensor means, Tensor quats, Tensor scales, Tensor sh, Tensor? sh_rest, Tensor cam, float fx, "
      "float fy, float cx, float cy, int width, int height, float near, float far, int sh_degree) -> "
      "(Tensor, Tensor, Tensor, Tensor, Tensor)",
      &project_forward);
  m.def(
      "project_backward(Tensor means, Tensor quats, Tensor scales, Tensor sh, Tensor? sh_rest, Tensor cam, "
      "float fx, float fy, float cx, float cy, int width, int height, float near, float far, int sh_degree, "
      "Tensor radii, "
      "Tensor grad_means2d, Tensor grad_conics, Tensor grad_depths, Tensor grad_colors) -> "
      "(Tensor, Tensor, Tensor, Tensor, Tensor)",
      &project_backward);
}
