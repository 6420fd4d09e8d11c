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
// hand-written derivatives against autograd of project.py to ~1e-12.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include "hot.h"

#include "phase_timer.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <tuple>

namespace {

constexpr double kLowPass = 0.3;     // project.LOW_PASS_DILATION
constexpr double kFrustumSlack = 1.3;  // project.FRUSTUM_SLACK
constexpr double kQuatEps = 1e-12;   // project.QUAT_EPS
constexpr double kDirEps = 1e-24;    // project.view_colors
constexpr double kMaxRadius = 1073741824.0;  // project.MAX_RADIUS = 2^30

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

template <typename S>
inline __attribute__((always_inline)) S rsqrt_clamped(S v, S eps) {
  return S(1) / std::sqrt(std::max(v, eps));
}

// Rotation matrix (row-major) of a unit quaternion (w, x, y, z), as project.quat_to_rotmat.
template <typename S>
inline __attribute__((always_inline)) void rotmat(S w, S x, S y, S z, S* R) {
  R[0] = 1 - 2 * (y * y + z * z);
  R[1] = 2 * (x * y - w * z);
  R[2] = 2 * (x * z + w * y);
  R[3] = 2 * (x * y + w * z);
  R[4] = 1 - 2 * (x * x + z * z);
  R[5] = 2 * (y * z - w * x);
  R[6] = 2 * (x * z - w * y);
  R[7] = 2 * (y * z + w * x);
  R[8] = 1 - 2 * (x * x + y * y);
}

// SH basis values (sh.py's eval_sh, term by term) along a unit direction; returns the count used.
template <typename S>
inline __attribute__((always_inline)) int sh_basis(int degree, S x, S y, S z, S* b) {
  b[0] = static_cast<S>(SH_C0);
  if (degree == 0) return 1;
  const S c1 = static_cast<S>(SH_C1);
  b[1] = -c1 * y;
  b[2] = c1 * z;
  b[3] = -c1 * x;
  if (degree == 1) return 4;
  const S xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  b[4] = static_cast<S>(SH_C2[0]) * xy;
  b[5] = static_cast<S>(SH_C2[1]) * yz;
  b[6] = static_cast<S>(SH_C2[2]) * (2 * zz - xx - yy);
  b[7] = static_cast<S>(SH_C2[3]) * xz;
  b[8] = static_cast<S>(SH_C2[4]) * (xx - yy);
  if (degree == 2) return 9;
  b[9] = static_cast<S>(SH_C3[0]) * y * (3 * xx - yy);
  b[10] = static_cast<S>(SH_C3[1]) * xy * z;
  b[11] = static_cast<S>(SH_C3[2]) * y * (4 * zz - xx - yy);
  b[12] = static_cast<S>(SH_C3[3]) * z * (2 * zz - 3 * xx - 3 * yy);
  b[13] = static_cast<S>(SH_C3[4]) * x * (4 * zz - xx - yy);
  b[14] = static_cast<S>(SH_C3[5]) * z * (xx - yy);
  b[15] = static_cast<S>(SH_C3[6]) * x * (xx - 3 * yy);
  return 16;
}

// d(basis_k)/d(x, y, z) for k < count, as rows [k][3].
template <typename S>
inline __attribute__((always_inline)) void sh_basis_grad(int degree, S x, S y, S z, S (*d)[3]) {
  for (int k = 0; k < 16; ++k) d[k][0] = d[k][1] = d[k][2] = 0;
  if (degree == 0) return;
  const S c1 = static_cast<S>(SH_C1);
  d[1][1] = -c1;
  d[2][2] = c1;
  d[3][0] = -c1;
  if (degree == 1) return;
  const S xx = x * x, yy = y * y, zz = z * z;
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
  d[9][0] = b0 * 6 * x * y, d[9][1] = b0 * (3 * xx - 3 * yy);
  d[10][0] = b1 * y * z, d[10][1] = b1 * x * z, d[10][2] = b1 * x * y;
  d[11][0] = b2 * (-2 * x * y), d[11][1] = b2 * (4 * zz - xx - 3 * yy), d[11][2] = b2 * 8 * y * z;
  d[12][0] = b3 * (-6 * x * z), d[12][1] = b3 * (-6 * y * z), d[12][2] = b3 * (6 * zz - 3 * xx - 3 * yy);
  d[13][0] = b4 * (4 * zz - 3 * xx - yy), d[13][1] = b4 * (-2 * x * y), d[13][2] = b4 * 8 * x * z;
  d[14][0] = b5 * 2 * x * z, d[14][1] = b5 * (-2 * y * z), d[14][2] = b5 * (xx - yy);
  d[15][0] = b6 * (3 * xx - 3 * yy), d[15][1] = b6 * (-6 * x * y);
}

// Everything of one Gaussian's projection the backward needs again (recomputed there, not stored).
template <typename S>
struct Proj {
  bool in_range, ok;
  S x, y, z;          // camera-space mean (safe point (0, 0, 1) when out of range)
  S txtz, tytz;       // unclamped x/z, y/z
  S J[6];             // 2x3
  S JW[6];            // J @ W, 2x3
  S Rq[9];            // rotation of the normalised quaternion
  S qn[4], q_inv;     // normalised quaternion and 1 / |q| (clamped)
  S M[9];             // Rq * diag(scales)
  S U[6];             // JW @ M
  S a, b, c, det;     // undilated covariance entries and the dilated determinant
  S a_s, b_s, c_s, det_s;
};

template <typename S>
inline __attribute__((always_inline)) void project_one(const Cam<S>& k, const S* m, const S* q, const S* s, Proj<S>& p) {
  const S* R = k.R;
  S pc[3];
  for (int r = 0; r < 3; ++r) pc[r] = R[3 * r] * m[0] + R[3 * r + 1] * m[1] + R[3 * r + 2] * m[2] + k.t[r];
  p.in_range = pc[2] > k.near_ && pc[2] < k.far_ && std::isfinite(pc[0]) && std::isfinite(pc[1]) &&
               std::isfinite(pc[2]);
  p.x = p.in_range ? pc[0] : S(0);
  p.y = p.in_range ? pc[1] : S(0);
  p.z = p.in_range ? pc[2] : S(1);
  const S x = p.x, y = p.y, z = p.z;
  p.txtz = x / z;
  p.tytz = y / z;
  const S cxz = std::min(std::max(p.txtz, -k.lim_left), k.lim_right);
  const S cyz = std::min(std::max(p.tytz, -k.lim_top), k.lim_bottom);
  p.J[0] = k.fx / z;
  p.J[1] = 0;
  p.J[2] = -k.fx * cxz / z;
  p.J[3] = 0;
  p.J[4] = k.fy / z;
  p.J[5] = -k.fy * cyz / z;
  for (int r = 0; r < 2; ++r)
    for (int col = 0; col < 3; ++col)
      p.JW[3 * r + col] = p.J[3 * r] * R[col] + p.J[3 * r + 1] * R[3 + col] + p.J[3 * r + 2] * R[6 + col];

  const S qq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
  p.q_inv = rsqrt_clamped(qq, static_cast<S>(kQuatEps));
  for (int i = 0; i < 4; ++i) p.qn[i] = q[i] * p.q_inv;
  rotmat(p.qn[0], p.qn[1], p.qn[2], p.qn[3], p.Rq);
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col) p.M[3 * r + col] = p.Rq[3 * r + col] * s[col];
  for (int r = 0; r < 2; ++r)
    for (int col = 0; col < 3; ++col)
      p.U[3 * r + col] = p.JW[3 * r] * p.M[col] + p.JW[3 * r + 1] * p.M[3 + col] + p.JW[3 * r + 2] * p.M[6 + col];
  const S* U = p.U;
  p.a = U[0] * U[0] + U[1] * U[1] + U[2] * U[2];
  p.b = U[0] * U[3] + U[1] * U[4] + U[2] * U[5];
  p.c = U[3] * U[3] + U[4] * U[4] + U[5] * U[5];
  const S m01 = U[0] * U[4] - U[1] * U[3];
  const S m02 = U[0] * U[5] - U[2] * U[3];
  const S m12 = U[1] * U[5] - U[2] * U[4];
  const S lp = static_cast<S>(kLowPass);
  p.det = m01 * m01 + m02 * m02 + m12 * m12 + lp * (p.a + p.c) + static_cast<S>(kLowPass * kLowPass);
  p.ok = p.in_range && p.det > 0 && std::isfinite(p.det);
  p.det_s = p.ok ? p.det : S(1);
  p.a_s = p.ok ? p.a + lp : S(1);
  p.b_s = p.ok ? p.b : S(0);
  p.c_s = p.ok ? p.c + lp : S(1);
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
void check_all(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales, const at::Tensor& sh,
               int64_t sh_degree) {
  const int64_t n = means.size(0);
  check_tensor<S>(means, "means", n, {3});
  check_tensor<S>(quats, "quats", n, {4});
  check_tensor<S>(scales, "scales", n, {3});
  check_tensor<S>(sh, "sh", n, {-1, 3});
  TORCH_CHECK(sh_degree >= 0 && sh_degree <= 3, "project_cpu: sh_degree must be 0-3, got ", sh_degree);
  TORCH_CHECK(sh.size(1) >= (sh_degree + 1) * (sh_degree + 1), "project_cpu: sh has ", sh.size(1),
              " coefficients per channel, degree ", sh_degree, " needs ", (sh_degree + 1) * (sh_degree + 1));
}

// Projection and colour of Gaussians [g0, g1) (one thread's share).
template <typename S>
GSGS_HOT void forward_range(const Cam<S>& k, const S* mp, const S* qp, const S* sp, const S* hp, int64_t n_coeffs,
                            int64_t sh_degree, S* o_m, S* o_k, S* o_d, S* o_c, int32_t* o_r, int64_t g0, int64_t g1) {
  Proj<S> p;
  for (int64_t g = g0; g < g1; ++g) {
    const S* m = mp + 3 * g;
    project_one(k, m, qp + 4 * g, sp + 3 * g, p);
    o_k[3 * g] = p.c_s / p.det_s;
    o_k[3 * g + 1] = -p.b_s / p.det_s;
    o_k[3 * g + 2] = p.a_s / p.det_s;
    const S mx = k.fx * p.x / p.z + k.cx;
    const S my = k.fy * p.y / p.z + k.cy;
    o_m[2 * g] = mx;
    o_m[2 * g + 1] = my;
    o_d[g] = p.z;
    // Radius from the largest eigenvalue, in double (no gradient).
    const double a64 = p.a_s, c64 = p.c_s, det64 = p.det_s;
    const double mid = 0.5 * (a64 + c64);
    const double lam = mid + std::sqrt(std::max(mid * mid - det64, 0.0));
    const double radius = std::ceil(3.0 * std::sqrt(std::max(lam, 0.0)));
    const double mx64 = mx, my64 = my;
    const bool on_screen = mx64 + radius > 0 && mx64 - radius < k.width && my64 + radius > 0 &&
                           my64 - radius < k.height;
    const bool visible = p.ok && on_screen && std::isfinite(radius);
    o_r[g] = visible ? static_cast<int32_t>(std::min(std::max(radius, 1.0), kMaxRadius)) : 0;

    // Colour along the view direction.
    S dir[3] = {m[0] - k.centre[0], m[1] - k.centre[1], m[2] - k.centre[2]};
    const S inv = rsqrt_clamped(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2], static_cast<S>(kDirEps));
    S basis[16];
    const int nb = sh_basis(static_cast<int>(sh_degree), dir[0] * inv, dir[1] * inv, dir[2] * inv, basis);
    const S* coeffs = hp + g * n_coeffs * 3;
    for (int ch = 0; ch < 3; ++ch) {
      S v = 0;
      for (int b = 0; b < nb; ++b) v += basis[b] * coeffs[3 * b + ch];
      v += S(0.5);
      o_c[3 * g + ch] = v >= 0 ? v : S(0);
    }
  }
}

// Gradients of Gaussians [g0, g1) (one thread's share).
template <typename S>
GSGS_HOT void backward_range(const Cam<S>& k, const S* mp, const S* qp, const S* sp, const S* hp, int64_t n_coeffs,
                             int deg, const int32_t* rp, const S* gm, const S* gk, const S* gd, const S* gc, S* dm_p,
                             S* dq_p, S* ds_p, S* dh_p, int64_t g0, int64_t g1) {
  Proj<S> p;
  for (int64_t g = g0; g < g1; ++g) {
    S* dm = dm_p + 3 * g;
    S* dq = dq_p + 4 * g;
    S* ds = ds_p + 3 * g;
    S* dh = dh_p + g * n_coeffs * 3;
    std::fill(dh, dh + n_coeffs * 3, S(0));
    if (rp[g] <= 0) {  // culled: the rasteriser ignores it, so nothing reaches its parameters
      std::fill(dm, dm + 3, S(0));
      std::fill(dq, dq + 4, S(0));
      std::fill(ds, ds + 3, S(0));
      continue;
    }
    const S* m = mp + 3 * g;
    const S* q = qp + 4 * g;
    const S* s = sp + 3 * g;
    project_one(k, m, q, s, p);
    const S x = p.x, y = p.y, z = p.z;

    // --- colour: SH + 0.5, clamp_min(0) --------------------------------------------------
    S dmean[3] = {0, 0, 0};
    {
      const S v[3] = {m[0] - k.centre[0], m[1] - k.centre[1], m[2] - k.centre[2]};
      const S vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
      const S inv = rsqrt_clamped(vv, static_cast<S>(kDirEps));
      const S d[3] = {v[0] * inv, v[1] * inv, v[2] * inv};
      S basis[16];
      const int nb = sh_basis(deg, d[0], d[1], d[2], basis);
      const S* coeffs = hp + g * n_coeffs * 3;
      S dcol[3];
      bool any = false;
      for (int ch = 0; ch < 3; ++ch) {
        S val = 0;
        for (int b = 0; b < nb; ++b) val += basis[b] * coeffs[3 * b + ch];
        val += S(0.5);
        dcol[ch] = val >= 0 ? gc[3 * g + ch] : S(0);
        any = any || dcol[ch] != 0;
      }
      for (int b = 0; b < nb; ++b)
        for (int ch = 0; ch < 3; ++ch) dh[3 * b + ch] = basis[b] * dcol[ch];
      if (any && deg > 0) {
        S db[16][3];
        sh_basis_grad(deg, d[0], d[1], d[2], db);
        S ddir[3] = {0, 0, 0};
        for (int b = 1; b < nb; ++b) {
          const S w = coeffs[3 * b] * dcol[0] + coeffs[3 * b + 1] * dcol[1] + coeffs[3 * b + 2] * dcol[2];
          for (int i = 0; i < 3; ++i) ddir[i] += w * db[b][i];
        }
        // d = v * rsqrt(max(|v|^2, eps)): dv = inv ddir - inv^3 (ddir . v) v where |v|^2 >= eps
        const S dot = ddir[0] * v[0] + ddir[1] * v[1] + ddir[2] * v[2];
        const S k3 = vv >= static_cast<S>(kDirEps) ? inv * inv * inv * dot : S(0);
        for (int i = 0; i < 3; ++i) dmean[i] += inv * ddir[i] - k3 * v[i];
      }
    }

    // --- camera-space point: means2d and depth ----------------------------------------------
    S dx = 0, dy = 0, dz = gd[g];
    {
      const S gmx = gm[2 * g], gmy = gm[2 * g + 1];
      dx += gmx * k.fx / z;
      dy += gmy * k.fy / z;
      dz -= (gmx * k.fx * x + gmy * k.fy * y) / (z * z);
    }

    // --- conic (c, -b, a) / det and the dilated determinant ------------------------------------
    S dU[6] = {0, 0, 0, 0, 0, 0};
    S dJW[6];
    if (p.ok) {
      const S* U = p.U;
      const S k0 = gk[3 * g], k1 = gk[3 * g + 1], k2 = gk[3 * g + 2];
      const S inv_det = S(1) / p.det;
      const S ddet = -(k0 * p.c_s - k1 * p.b_s + k2 * p.a_s) * inv_det * inv_det;
      const S lp = static_cast<S>(kLowPass);
      const S da = k2 * inv_det + lp * ddet;
      const S dc = k0 * inv_det + lp * ddet;
      const S db = -k1 * inv_det;
      const S m01 = U[0] * U[4] - U[1] * U[3];
      const S m02 = U[0] * U[5] - U[2] * U[3];
      const S m12 = U[1] * U[5] - U[2] * U[4];
      const S d01 = 2 * m01 * ddet, d02 = 2 * m02 * ddet, d12 = 2 * m12 * ddet;
      for (int i = 0; i < 3; ++i) {
        dU[i] += 2 * da * U[i] + db * U[3 + i];
        dU[3 + i] += 2 * dc * U[3 + i] + db * U[i];
      }
      dU[0] += d01 * U[4] + d02 * U[5];
      dU[4] += d01 * U[0] - d12 * U[2];
      dU[1] += -d01 * U[3] + d12 * U[5];
      dU[3] += -d01 * U[1] - d02 * U[2];
      dU[5] += d02 * U[0] + d12 * U[1];
      dU[2] += -d02 * U[3] - d12 * U[4];
    }
    // U = JW M: dJW = dU M^T, dM = JW^T dU
    S dM[9];
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c)
        dJW[3 * r + c] = dU[3 * r] * p.M[3 * c] + dU[3 * r + 1] * p.M[3 * c + 1] + dU[3 * r + 2] * p.M[3 * c + 2];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) dM[3 * r + c] = p.JW[r] * dU[c] + p.JW[3 + r] * dU[3 + c];
    // JW = J W: dJ = dJW W^T (only J00, J02, J11, J12 depend on the point)
    const S* R = k.R;
    S dJ[6];
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c)
        dJ[3 * r + c] = dJW[3 * r] * R[3 * c] + dJW[3 * r + 1] * R[3 * c + 1] + dJW[3 * r + 2] * R[3 * c + 2];
    {
      const S cxz = std::min(std::max(p.txtz, -k.lim_left), k.lim_right);
      const S cyz = std::min(std::max(p.tytz, -k.lim_top), k.lim_bottom);
      const S z2 = z * z;
      dz += -dJ[0] * k.fx / z2 + dJ[2] * k.fx * cxz / z2 - dJ[4] * k.fy / z2 + dJ[5] * k.fy * cyz / z2;
      const S dtx = -dJ[2] * k.fx / z;
      const S dty = -dJ[5] * k.fy / z;
      if (p.txtz >= -k.lim_left && p.txtz <= k.lim_right) {
        dx += dtx / z;
        dz -= dtx * x / z2;
      }
      if (p.tytz >= -k.lim_top && p.tytz <= k.lim_bottom) {
        dy += dty / z;
        dz -= dty * y / z2;
      }
    }
    // p_cam = R m + t
    if (p.in_range) {
      for (int i = 0; i < 3; ++i) dmean[i] += R[i] * dx + R[3 + i] * dy + R[6 + i] * dz;
    }
    for (int i = 0; i < 3; ++i) dm[i] = dmean[i];

    // M = Rq diag(s)
    S dR[9];
    for (int c = 0; c < 3; ++c) {
      ds[c] = dM[c] * p.Rq[c] + dM[3 + c] * p.Rq[3 + c] + dM[6 + c] * p.Rq[6 + c];
      for (int r = 0; r < 3; ++r) dR[3 * r + c] = dM[3 * r + c] * s[c];
    }
    // Rq(w, x, y, z) of the normalised quaternion
    const S w = p.qn[0], qx = p.qn[1], qy = p.qn[2], qz = p.qn[3];
    S dqn[4];
    dqn[0] = 2 * (-qz * dR[1] + qy * dR[2] + qz * dR[3] - qx * dR[5] - qy * dR[6] + qx * dR[7]);
    dqn[1] = 2 * (qy * dR[1] + qz * dR[2] + qy * dR[3] - 2 * qx * dR[4] - w * dR[5] + qz * dR[6] + w * dR[7] -
                  2 * qx * dR[8]);
    dqn[2] = 2 * (-2 * qy * dR[0] + qx * dR[1] + w * dR[2] + qx * dR[3] + qz * dR[5] - w * dR[6] + qz * dR[7] -
                  2 * qy * dR[8]);
    dqn[3] = 2 * (-2 * qz * dR[0] - w * dR[1] + qx * dR[2] + w * dR[3] - 2 * qz * dR[4] + qy * dR[5] +
                  qx * dR[6] + qy * dR[7]);
    // qn = q rsqrt(max(|q|^2, eps))
    const S qq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    const S inv = p.q_inv;
    const S dot = dqn[0] * q[0] + dqn[1] * q[1] + dqn[2] * q[2] + dqn[3] * q[3];
    const S k3 = qq >= static_cast<S>(kQuatEps) ? inv * inv * inv * dot : S(0);
    for (int i = 0; i < 4; ++i) dq[i] = inv * dqn[i] - k3 * q[i];
  }
}

using ProjectResult = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

template <typename S>
ProjectResult forward_impl(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                           const at::Tensor& sh, const at::Tensor& cam, double fx, double fy, double cx, double cy,
                           int64_t width, int64_t height, double near_, double far_, int64_t sh_degree) {
  gsgs_phase::Lap lap;
  check_all<S>(means, quats, scales, sh, sh_degree);
  const Cam<S> k = make_cam<S>(cam, fx, fy, cx, cy, width, height, near_, far_);
  const int64_t n = means.size(0);
  const int64_t n_coeffs = sh.size(1);
  const auto opts = means.options();
  at::Tensor means2d = at::empty({n, 2}, opts);
  at::Tensor conics = at::empty({n, 3}, opts);
  at::Tensor depths = at::empty({n}, opts);
  at::Tensor colors = at::empty({n, 3}, opts);
  at::Tensor radii = at::empty({n}, opts.dtype(at::kInt));
  const S* mp = means.data_ptr<S>();
  const S* qp = quats.data_ptr<S>();
  const S* sp = scales.data_ptr<S>();
  const S* hp = sh.data_ptr<S>();
  S* o_m = means2d.data_ptr<S>();
  S* o_k = conics.data_ptr<S>();
  S* o_d = depths.data_ptr<S>();
  S* o_c = colors.data_ptr<S>();
  int32_t* o_r = radii.data_ptr<int32_t>();
  at::parallel_for(0, n, 1024, [&](int64_t g0, int64_t g1) {
    forward_range(k, mp, qp, sp, hp, n_coeffs, sh_degree, o_m, o_k, o_d, o_c, o_r, g0, g1);
  });
  lap(gsgs_phase::kProjectForward);
  return {means2d, conics, depths, radii, colors};
}

using ProjectGrads = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

template <typename S>
ProjectGrads backward_impl(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                           const at::Tensor& sh, const at::Tensor& cam, double fx, double fy, double cx, double cy,
                           int64_t width, int64_t height, double near_, double far_, int64_t sh_degree,
                           const at::Tensor& radii, const at::Tensor& g_means2d, const at::Tensor& g_conics,
                           const at::Tensor& g_depths, const at::Tensor& g_colors) {
  gsgs_phase::Lap lap;
  check_all<S>(means, quats, scales, sh, sh_degree);
  const int64_t n = means.size(0);
  check_tensor<S>(g_means2d, "grad means2d", n, {2});
  check_tensor<S>(g_conics, "grad conics", n, {3});
  check_tensor<S>(g_depths, "grad depths", n, {});
  check_tensor<S>(g_colors, "grad colors", n, {3});
  TORCH_CHECK(radii.scalar_type() == at::kInt && radii.is_contiguous() && radii.numel() == n,
              "project_cpu backward: radii must be int32 [N]");
  const Cam<S> k = make_cam<S>(cam, fx, fy, cx, cy, width, height, near_, far_);
  const int64_t n_coeffs = sh.size(1);
  at::Tensor d_means = at::empty({n, 3}, means.options());
  at::Tensor d_quats = at::empty({n, 4}, means.options());
  at::Tensor d_scales = at::empty({n, 3}, means.options());
  at::Tensor d_sh = at::empty({n, n_coeffs, 3}, means.options());
  const S* mp = means.data_ptr<S>();
  const S* qp = quats.data_ptr<S>();
  const S* sp = scales.data_ptr<S>();
  const S* hp = sh.data_ptr<S>();
  const int32_t* rp = radii.data_ptr<int32_t>();
  const S* gm = g_means2d.data_ptr<S>();
  const S* gk = g_conics.data_ptr<S>();
  const S* gd = g_depths.data_ptr<S>();
  const S* gc = g_colors.data_ptr<S>();
  S* dm_p = d_means.data_ptr<S>();
  S* dq_p = d_quats.data_ptr<S>();
  S* ds_p = d_scales.data_ptr<S>();
  S* dh_p = d_sh.data_ptr<S>();
  const int deg = static_cast<int>(sh_degree);
  at::parallel_for(0, n, 512, [&](int64_t g0, int64_t g1) {
    backward_range(k, mp, qp, sp, hp, n_coeffs, deg, rp, gm, gk, gd, gc, dm_p, dq_p, ds_p, dh_p, g0, g1);
  });
  lap(gsgs_phase::kProjectBackward);
  return {d_means, d_quats, d_scales, d_sh};
}

ProjectResult project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                              const at::Tensor& sh, const at::Tensor& cam, double fx, double fy, double cx, double cy,
                              int64_t width, int64_t height, double near_, double far_, int64_t sh_degree) {
  TORCH_CHECK(means.dim() == 2, "project_cpu: means must be [N, 3]");
  TORCH_CHECK(width > 0 && height > 0, "project_cpu: image size must be positive");
  if (means.scalar_type() == at::kDouble)
    return forward_impl<double>(means, quats, scales, sh, cam, fx, fy, cx, cy, width, height, near_, far_, sh_degree);
  return forward_impl<float>(means, quats, scales, sh, cam, fx, fy, cx, cy, width, height, near_, far_, sh_degree);
}

ProjectGrads project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                              const at::Tensor& sh, const at::Tensor& cam, double fx, double fy, double cx, double cy,
                              int64_t width, int64_t height, double near_, double far_, int64_t sh_degree,
                              const at::Tensor& radii, const at::Tensor& g_means2d, const at::Tensor& g_conics,
                              const at::Tensor& g_depths, const at::Tensor& g_colors) {
  TORCH_CHECK(means.dim() == 2, "project_cpu: means must be [N, 3]");
  if (means.scalar_type() == at::kDouble)
    return backward_impl<double>(means, quats, scales, sh, cam, fx, fy, cx, cy, width, height, near_, far_, sh_degree,
                                 radii, g_means2d, g_conics, g_depths, g_colors);
  return backward_impl<float>(means, quats, scales, sh, cam, fx, fy, cx, cy, width, height, near_, far_, sh_degree,
                              radii, g_means2d, g_conics, g_depths, g_colors);
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(gsgs_raster_cpu, m) {
  m.def(
      "project_forward(Tensor means, Tensor quats, Tensor scales, Tensor sh, Tensor cam, float fx, float fy, "
      "float cx, float cy, int width, int height, float near, float far, int sh_degree) -> "
      "(Tensor, Tensor, Tensor, Tensor, Tensor)",
      &project_forward);
  m.def(
      "project_backward(Tensor means, Tensor quats, Tensor scales, Tensor sh, Tensor cam, float fx, float fy, "
      "float cx, float cy, int width, int height, float near, float far, int sh_degree, Tensor radii, "
      "Tensor grad_means2d, Tensor grad_conics, Tensor grad_depths, Tensor grad_colors) -> "
      "(Tensor, Tensor, Tensor, Tensor)",
      &project_backward);
}
