// gsgs compiled SSIM for the training loss: mean SSIM of an [H, W, C] image against a target, and its
// gradient with respect to the image, in one call.
//
// Semantics are those of gsgs_engine/metrics.ssim_map (3DGS's loss_utils.ssim): a separable Gaussian
// window (weights passed in), zero padding of half the window so the map has the image's size,
// C1 = 0.01^2, C2 = 0.03^2, the mean over every pixel and channel. Per channel: five blurred maps
// (x, y, x^2, y^2, xy) forward; the gradient needs three more blurs, because the blur with zero padding
// and a symmetric window is its own adjoint:
//   dS/dx_p = blur(dS/dmu1)_p + 2 x_p blur(dS/de11)_p + y_p blur(dS/de12)_p,
// with, per pixel, ssim = A B / (Cc D), A = 2 mu1 mu2 + C1, B = 2 s12 + C2, Cc = mu1^2 + mu2^2 + C1,
// D = s11 + s22 + C2 (s11 = e11 - mu1^2, s12 = e12 - mu1 mu2):
//   dS/dmu1 = ssim (2 mu2 / A - 2 mu2 / B - 2 mu1 / Cc + 2 mu1 / D),  dS/de11 = -ssim / D,
//   dS/de12 = 2 ssim / B (evaluated as 2 A / (Cc D): B may be 0).
// With a mask m (H x W weights) the value is the masked mean of the channel-mean SSIM map,
// sum_p m_p mean_c ssim_pc / max(sum_p m_p, 1) (losses.dssim_loss's torch form): each pixel's coefficients are
// scaled by m_p before the gradient's blurs, and the mean divides by C max(sum m, 1).
// Strips of rows are split over ATen's threads; every output value is computed by one thread in a fixed order and
// the mean is summed per row, then over rows in order, so the result does not depend on the thread count.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include "hot.h"
#include "reusable_buffer.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <tuple>
#include <type_traits>
#include <vector>

namespace {

// The work goes in strips of kStrip output rows of one channel: the maps a strip needs (its rows and `taps / 2`
// rows either side) are made and blurred along x into a small buffer that stays in cache, then blurred along y
// row by row. The whole-image version wrote and re-read 16 planes per channel (about 94 MB a call at 400x400x3,
// memory-bound); this writes the three coefficient planes and the gradient. Every value is the same sum in the
// same order as blurring whole planes (each tap added in order k = 0 .. taps - 1, from 0, the taps outside the
// image skipped), so the result is the same to the bit.
constexpr int kStrip = 32;

// Eight float lanes (GCC vector extensions), loaded and stored unaligned through memcpy. The float blurs keep eight
// pixels' sums in a register across the taps (one load and a multiply-add per tap, instead of reading and writing
// the output at every tap); each sum still adds its taps in order k = 0 .. taps - 1 from 0.
typedef float v8f __attribute__((vector_size(32)));
constexpr int kLanes = 8;
inline __attribute__((always_inline)) v8f load8(const float* p) {
  v8f v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline __attribute__((always_inline)) void store8(float* p, v8f v) { std::memcpy(p, &v, sizeof v); }

// dst[0 .. Vecs * 8) = sum over taps k in [k0, k1) of w[k] * tap(k)[0 .. Vecs * 8), each lane's sum in order k0, k0 + 1,
// ... from 0; Vecs independent sums at a time keep the adders busy.
template <int Vecs, typename Tap>
inline __attribute__((always_inline)) void sum_taps(Tap tap, const float* w, int k0, int k1, float* dst) {
  v8f acc[Vecs] = {};
  for (int k = k0; k < k1; ++k) {
    const float* p = tap(k);
    const float wk = w[k];
    for (int j = 0; j < Vecs; ++j) acc[j] += wk * load8(p + j * kLanes);
  }
  for (int j = 0; j < Vecs; ++j) store8(dst + j * kLanes, acc[j]);
}

// out[x] = sum_k w[k] in[x + k - r] (zero outside) for one row of W values.
template <typename S>
inline __attribute__((always_inline)) void blur_row(const S* src, S* dst, int W, const S* w, int taps) {
  const int r = taps / 2;
  int x = 0;
  if constexpr (std::is_same_v<S, float>) {
    // every tap inside the row
    for (x = r; x + 4 * kLanes - 1 + r < W; x += 4 * kLanes)
      sum_taps<4>([&](int k) { return src + x + k - r; }, w, 0, taps, dst + x);
    for (; x + kLanes - 1 + r < W; x += kLanes) sum_taps<1>([&](int k) { return src + x + k - r; }, w, 0, taps, dst + x);
  }
  const int inner_end = x > r ? x : 0;  // [r, inner_end) done above
  for (x = 0; x < W; ++x) {
    if (x >= r && x < inner_end) x = inner_end;
    if (x >= W) break;
    S acc = 0;
    for (int k = 0; k < taps; ++k) {
      const int xx = x + k - r;
      if (xx >= 0 && xx < W) acc += w[k] * src[xx];
    }
    dst[x] = acc;
  }
}

// out[x] = sum_k w[k] rows[y + k - r][x] (rows outside [0, H) skipped); `rows(yy)` gives row yy of the x-blurred map.
template <typename S, typename Rows>
inline __attribute__((always_inline)) void blur_col(Rows rows, S* dst, int y, int H, int W, const S* w, int taps) {
  const int r = taps / 2;
  const int k0 = std::max(0, r - y), k1 = std::min(taps, H + r - y);  // the taps whose row exists
  int x = 0;
  if constexpr (std::is_same_v<S, float>) {
    for (; x + 4 * kLanes <= W; x += 4 * kLanes)
      sum_taps<4>([&](int k) { return rows(y + k - r) + x; }, w, k0, k1, dst + x);
    for (; x + kLanes <= W; x += kLanes) sum_taps<1>([&](int k) { return rows(y + k - r) + x; }, w, k0, k1, dst + x);
  }
  for (; x < W; ++x) {
    S acc = 0;
    for (int k = k0; k < k1; ++k) acc += w[k] * rows(y + k - r)[x];
    dst[x] = acc;
  }
}

struct SsimShape {
  int H, W, C, taps;
};

// Scratch values one strip needs (the larger of the two passes).
inline size_t strip_scratch(const SsimShape& d) {
  const size_t rows_in = static_cast<size_t>(std::min(d.H, kStrip + 2 * (d.taps / 2)));
  return (5 * rows_in + 11) * static_cast<size_t>(d.W);
}

// Strip `job`: channel c, output rows [y0, y1), input rows [ya, yb) (the output rows and taps / 2 either side).
struct Strip {
  int c, y0, y1, ya, yb;
};
inline Strip strip_of(int64_t job, const SsimShape& d) {
  const int r = d.taps / 2;
  const int y0 = static_cast<int>(job / d.C) * kStrip, y1 = std::min(d.H, y0 + kStrip);
  return {static_cast<int>(job % d.C), y0, y1, std::max(0, y0 - r), std::min(d.H, y1 + r)};
}

// One row's SSIM values (sv) and gradient coefficients (k, k + plane, k + 2 plane) from its five blurred maps
// (vb: mu1, mu2, e11, e22, e12, W values each). No reduction and no aliasing here, so the loop is vectorised.
template <typename S>
inline __attribute__((always_inline)) void ssim_row(const S* __restrict vb, int W, S c1, S c2, S* __restrict sv,
                                                    S* __restrict k, int64_t plane) {
  S* __restrict k1 = k + plane;
  S* __restrict k2 = k + 2 * plane;
  for (int x = 0; x < W; ++x) {
    const S mu1 = vb[x], mu2 = vb[W + x];
    const S e11 = vb[2 * W + x], e22 = vb[3 * W + x], e12 = vb[4 * W + x];
    const S mu1_sq = mu1 * mu1, mu2_sq = mu2 * mu2, mu12 = mu1 * mu2;
    const S s11 = e11 - mu1_sq, s22 = e22 - mu2_sq, s12 = e12 - mu12;
    const S A = 2 * mu12 + c1, B = 2 * s12 + c2, Cc = mu1_sq + mu2_sq + c1, D = s11 + s22 + c2;
    const S inv = 1 / (Cc * D);
    const S s = (A * B) * inv;
    sv[x] = s;
    // s / A and s / B written without dividing by A or B (either may be 0: mu1 mu2 < 0, s12 < 0)
    k[x] = 2 * mu2 * (B - A) * inv + 2 * mu1 * s * (1 / D - 1 / Cc);
    k1[x] = -s / D;
    k2[x] = 2 * A * inv;
  }
}

// Forward of strip `job` (channel job % C, rows from (job / C) * kStrip): the SSIM of each pixel (summed per row into
// row_sum[c * H + y], in double, in order) and the three coefficient planes of its gradient, from the five blurred
// maps x, y, x^2, y^2, x y.
template <typename S>
GSGS_HOT void ssim_forward_strips(const S* xi, const S* yi, const S* w, const S* mask, SsimShape d, S c1, S c2,
                                  S* coef, double* row_sum, S* scratch, int64_t job0, int64_t job1) {
  const int H = d.H, W = d.W;
  const int64_t plane = static_cast<int64_t>(H) * W;
  for (int64_t job = job0; job < job1; ++job) {
    const Strip st = strip_of(job, d);
    const int c = st.c, y0 = st.y0, y1 = st.y1, ya = st.ya, rows_in = st.yb - st.ya;
    S* const prod = scratch;                                    // [5][W]: one input row's maps
    S* const hb = prod + 5 * static_cast<int64_t>(W);           // [5][rows_in][W]: blurred along x
    S* const vb = hb + 5 * static_cast<int64_t>(rows_in) * W;   // [5][W]: one output row, blurred along y too; [W]
    for (int yy = ya; yy < st.yb; ++yy) {
      for (int x = 0; x < W; ++x) {
        const int64_t p = static_cast<int64_t>(yy) * W + x;
        const S xv = xi[p * d.C + c], yv = yi[p * d.C + c];
        prod[x] = xv;
        prod[W + x] = yv;
        prod[2 * W + x] = xv * xv;
        prod[3 * W + x] = yv * yv;
        prod[4 * W + x] = xv * yv;
      }
      for (int m = 0; m < 5; ++m) blur_row(prod + m * W, hb + (static_cast<int64_t>(m) * rows_in + yy - ya) * W, W, w,
                                           d.taps);
    }
    for (int y = y0; y < y1; ++y) {
      for (int m = 0; m < 5; ++m) {
        const S* map = hb + static_cast<int64_t>(m) * rows_in * W;
        blur_col<S>([&](int yy) { return map + static_cast<int64_t>(yy - ya) * W; }, vb + m * W, y, H, W, w, d.taps);
      }
      S* const sv = vb + 5 * static_cast<int64_t>(W);  // [W]: this row's SSIM values
      S* const k = coef + 3 * c * plane + static_cast<int64_t>(y) * W;
      ssim_row(vb, W, c1, c2, sv, k, plane);
      double sum = 0.0;
      if (mask == nullptr) {
        for (int x = 0; x < W; ++x) sum += static_cast<double>(sv[x]);
      } else {  // each pixel's SSIM and its gradient coefficients weighted by the mask
        const S* const mr = mask + static_cast<int64_t>(y) * W;
        for (int x = 0; x < W; ++x) {
          sum += static_cast<double>(mr[x] * sv[x]);
          k[x] *= mr[x];
          k[plane + x] *= mr[x];
          k[2 * plane + x] *= mr[x];
        }
      }
      row_sum[static_cast<int64_t>(c) * H + y] = sum;
    }
  }
}

// Gradient of strip `job`: the three coefficient planes blurred (the zero-padded symmetric blur is its own
// adjoint), then dS/dx_p = k0 + 2 x_p k1 + y_p k2, divided by the number of values.
template <typename S>
GSGS_HOT void ssim_backward_strips(const S* xi, const S* yi, const S* w, SsimShape d, const S* coef, S inv_count,
                                   S* g, S* scratch, int64_t job0, int64_t job1) {
  const int H = d.H, W = d.W;
  const int64_t plane = static_cast<int64_t>(H) * W;
  for (int64_t job = job0; job < job1; ++job) {
    const Strip st = strip_of(job, d);
    const int c = st.c, y0 = st.y0, y1 = st.y1, ya = st.ya, rows_in = st.yb - st.ya;
    S* const hb = scratch;                                      // [3][rows_in][W]
    S* const kb = hb + 3 * static_cast<int64_t>(rows_in) * W;   // [3][W]
    for (int m = 0; m < 3; ++m)
      for (int yy = ya; yy < st.yb; ++yy)
        blur_row(coef + (3 * c + m) * plane + static_cast<int64_t>(yy) * W,
                 hb + (static_cast<int64_t>(m) * rows_in + yy - ya) * W, W, w, d.taps);
    for (int y = y0; y < y1; ++y) {
      for (int m = 0; m < 3; ++m) {
        const S* map = hb + static_cast<int64_t>(m) * rows_in * W;
        blur_col<S>([&](int yy) { return map + static_cast<int64_t>(yy - ya) * W; }, kb + m * W, y, H, W, w, d.taps);
      }
      for (int x = 0; x < W; ++x) {
        const int64_t p = static_cast<int64_t>(y) * W + x;
        const S xv = xi[p * d.C + c], yv = yi[p * d.C + c];
        g[p * d.C + c] = (kb[x] + 2 * xv * kb[W + x] + yv * kb[2 * W + x]) * inv_count;
      }
    }
  }
}

template <typename S>
std::tuple<at::Tensor, at::Tensor> ssim_impl(const at::Tensor& img, const at::Tensor& target, const at::Tensor& window,
                                             const S* mask, double c1_d, double c2_d) {
  const SsimShape d{static_cast<int>(img.size(0)), static_cast<int>(img.size(1)), static_cast<int>(img.size(2)),
                    static_cast<int>(window.numel())};
  const int64_t plane = static_cast<int64_t>(d.H) * d.W;
  const S c1 = static_cast<S>(c1_d), c2 = static_cast<S>(c2_d);
  const S* w = window.data_ptr<S>();
  const S* xi = img.data_ptr<S>();
  const S* yi = target.data_ptr<S>();
  // The coefficient planes, reused between calls (every value is written before it is read).
  S* const coef = gsgs_scratch::reusable_buffer<S, 0>(static_cast<size_t>(3 * d.C) * plane);
  const int64_t jobs = static_cast<int64_t>((d.H + kStrip - 1) / kStrip) * d.C;
  const size_t scratch_len = strip_scratch(d);

  std::vector<double> row_sum(static_cast<size_t>(d.C) * d.H, 0.0);
  at::parallel_for(0, jobs, 1, [&](int64_t j0, int64_t j1) {
    S* scratch = gsgs_scratch::reusable_buffer<S, 1>(scratch_len);  // this worker's own
    ssim_forward_strips(xi, yi, w, mask, d, c1, c2, coef, row_sum.data(), scratch, j0, j1);
  });
  double total = 0.0;
  for (double v : row_sum) total += v;
  double count = static_cast<double>(plane) * d.C;
  if (mask != nullptr) {  // C max(sum m, 1), the weights summed in double in order
    double weight = 0.0;
    for (int64_t p = 0; p < plane; ++p) weight += static_cast<double>(mask[p]);
    count = d.C * std::max(weight, 1.0);
  }

  at::Tensor grad = at::empty_like(img);
  const S inv_count = static_cast<S>(1.0 / count);
  S* g = grad.data_ptr<S>();
  at::parallel_for(0, jobs, 1, [&](int64_t j0, int64_t j1) {
    S* scratch = gsgs_scratch::reusable_buffer<S, 1>(scratch_len);
    ssim_backward_strips(xi, yi, w, d, coef, inv_count, g, scratch, j0, j1);
  });
  at::Tensor mean = at::full({}, total / count, img.options());
  return {mean, grad};
}

// -> (mean SSIM, d mean / d img), for img and target [H, W, C] of one float dtype; with `mask` [H, W] (the same
// dtype) the masked mean (file comment).
std::tuple<at::Tensor, at::Tensor> ssim_forward_backward(const at::Tensor& img, const at::Tensor& target,
                                                         const at::Tensor& window, const c10::optional<at::Tensor>& mask,
                                                         double c1, double c2) {
  TORCH_CHECK(img.device().is_cpu() && target.device().is_cpu() && window.device().is_cpu(),
              "ssim_cpu: CPU tensors only");
  TORCH_CHECK(img.dim() == 3 && img.sizes() == target.sizes(), "ssim_cpu: img and target must both be [H, W, C], got ",
              img.sizes(), " and ", target.sizes());
  TORCH_CHECK(img.scalar_type() == target.scalar_type() && img.scalar_type() == window.scalar_type() &&
                  (img.scalar_type() == at::kFloat || img.scalar_type() == at::kDouble),
              "ssim_cpu: img, target and window must share one dtype, float32 or float64");
  TORCH_CHECK(img.is_contiguous() && target.is_contiguous() && window.is_contiguous(), "ssim_cpu: contiguous tensors only");
  TORCH_CHECK(window.dim() == 1 && window.numel() % 2 == 1, "ssim_cpu: the window must be 1D with an odd length");
  TORCH_CHECK(img.numel() > 0, "ssim_cpu: empty image");
  const at::Tensor* m = mask.has_value() ? &mask.value() : nullptr;
  if (m != nullptr) {
    TORCH_CHECK(m->device().is_cpu() && m->scalar_type() == img.scalar_type() && m->is_contiguous() &&
                    m->dim() == 2 && m->size(0) == img.size(0) && m->size(1) == img.size(1),
                "ssim_cpu: the mask must be a contiguous [H, W] CPU tensor of the image's dtype, got ", m->sizes());
  }
  if (img.scalar_type() == at::kDouble)
    return ssim_impl<double>(img, target, window, m ? m->data_ptr<double>() : nullptr, c1, c2);
  return ssim_impl<float>(img, target, window, m ? m->data_ptr<float>() : nullptr, c1, c2);
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(gsgs_raster_cpu, m) {
  m.def("ssim_forward_backward(Tensor img, Tensor target, Tensor window, Tensor? mask, float c1, float c2) -> "
        "(Tensor, Tensor)",
        &ssim_forward_backward);
}
