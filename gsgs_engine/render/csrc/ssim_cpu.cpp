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
// Rows are split over ATen's threads; every output value is computed by one thread in a fixed order and
// the mean is summed per row, then over rows in order, so the result does not depend on the thread count.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include "hot.h"
#include "reusable_buffer.h"

#include <algorithm>
#include <cstdint>
#include <tuple>
#include <vector>

namespace {

// Rows [r0, r1) of out[m][y][x] = sum_k w[k] in[m][y][x + k - r] (zero outside).
template <typename S>
GSGS_HOT void blur_rows_range(const S* in, S* out, int W, const S* w, int taps, int64_t r0, int64_t r1) {
  const int r = taps / 2;
  for (int64_t row = r0; row < r1; ++row) {
    const S* src = in + row * W;
    S* dst = out + row * W;
    for (int x = 0; x < W; ++x) dst[x] = 0;
    for (int k = 0; k < taps; ++k) {
      const int off = k - r;
      const int x0 = std::max(0, -off), x1 = std::min(W, W - off);
      const S wk = w[k];
      for (int x = x0; x < x1; ++x) dst[x] += wk * src[x + off];
    }
  }
}

// Rows [r0, r1) (of maps x H) of out[m][y][x] = sum_k w[k] in[m][y + k - r][x] (zero outside).
template <typename S>
GSGS_HOT void blur_cols_range(const S* in, S* out, int H, int W, const S* w, int taps, int64_t r0, int64_t r1) {
  const int r = taps / 2;
  for (int64_t row = r0; row < r1; ++row) {
    const int64_t m = row / H;
    const int y = static_cast<int>(row % H);
    S* dst = out + row * W;
    for (int x = 0; x < W; ++x) dst[x] = 0;
    for (int k = 0; k < taps; ++k) {
      const int yy = y + k - r;
      if (yy < 0 || yy >= H) continue;
      const S* src = in + (m * H + yy) * W;
      const S wk = w[k];
      for (int x = 0; x < W; ++x) dst[x] += wk * src[x];
    }
  }
}

// The 1D blur along x, then along y, of `maps` planes of H x W: in -> out, `tmp` in between.
template <typename S>
void blur(const S* in, S* tmp, S* out, int maps, int H, int W, const S* w, int taps) {
  const int64_t rows = static_cast<int64_t>(maps) * H;
  at::parallel_for(0, rows, 16, [&](int64_t r0, int64_t r1) { blur_rows_range(in, tmp, W, w, taps, r0, r1); });
  at::parallel_for(0, rows, 16, [&](int64_t r0, int64_t r1) { blur_cols_range(tmp, out, H, W, w, taps, r0, r1); });
}

template <typename S>
std::tuple<at::Tensor, at::Tensor> ssim_impl(const at::Tensor& img, const at::Tensor& target, const at::Tensor& window,
                                             double c1_d, double c2_d) {
  const int H = static_cast<int>(img.size(0)), W = static_cast<int>(img.size(1)), C = static_cast<int>(img.size(2));
  const int taps = static_cast<int>(window.numel());
  const int64_t plane = static_cast<int64_t>(H) * W;
  const S c1 = static_cast<S>(c1_d), c2 = static_cast<S>(c2_d);
  const S* w = window.data_ptr<S>();
  const S* xi = img.data_ptr<S>();
  const S* yi = target.data_ptr<S>();

  // One scratch buffer for every plane below, reused between calls; every plane is written in full
  // before it is read.
  S* const maps = gsgs_scratch::reusable_buffer<S, 0>(static_cast<size_t>(16 * C) * plane);
  // Planes per channel: x, y, xx, yy, xy (then blurred in place through `tmp`).
  S* const tmp = maps + static_cast<int64_t>(5 * C) * plane;
  S* const coef = tmp + static_cast<int64_t>(5 * C) * plane;
  S* const coef_blur = coef + static_cast<int64_t>(3 * C) * plane;
  at::parallel_for(0, plane, 4096, [&](int64_t p0, int64_t p1) {
    for (int c = 0; c < C; ++c) {
      S* base = maps + static_cast<int64_t>(5 * c) * plane;
      for (int64_t p = p0; p < p1; ++p) {
        const S x = xi[p * C + c], y = yi[p * C + c];
        base[p] = x;
        base[plane + p] = y;
        base[2 * plane + p] = x * x;
        base[3 * plane + p] = y * y;
        base[4 * plane + p] = x * y;
      }
    }
  });
  blur(maps, tmp, maps, 5 * C, H, W, w, taps);

  // Per pixel: the SSIM value (summed per row) and the three coefficient maps of the gradient.
  std::vector<double> row_sum(static_cast<size_t>(C) * H, 0.0);
  at::parallel_for(0, static_cast<int64_t>(C) * H, 16, [&](int64_t r0, int64_t r1) {
    for (int64_t row = r0; row < r1; ++row) {
      const int64_t c = row / H, y = row % H;
      const S* base = maps + 5 * c * plane + y * W;
      S* k = coef + 3 * c * plane + y * W;
      double sum = 0.0;
      for (int x = 0; x < W; ++x) {
        const S mu1 = base[x], mu2 = base[plane + x];
        const S e11 = base[2 * plane + x], e22 = base[3 * plane + x], e12 = base[4 * plane + x];
        const S mu1_sq = mu1 * mu1, mu2_sq = mu2 * mu2, mu12 = mu1 * mu2;
        const S s11 = e11 - mu1_sq, s22 = e22 - mu2_sq, s12 = e12 - mu12;
        const S A = 2 * mu12 + c1, B = 2 * s12 + c2, Cc = mu1_sq + mu2_sq + c1, D = s11 + s22 + c2;
        const S inv = 1 / (Cc * D);
        const S s = (A * B) * inv;
        sum += static_cast<double>(s);
        // s / A and s / B written without dividing by A or B (either may be 0: mu1 mu2 < 0, s12 < 0)
        k[x] = 2 * mu2 * (B - A) * inv + 2 * mu1 * s * (1 / D - 1 / Cc);
        k[plane + x] = -s / D;
        k[2 * plane + x] = 2 * A * inv;
      }
      row_sum[row] = sum;
    }
  });
  double total = 0.0;
  for (double v : row_sum) total += v;
  const double count = static_cast<double>(plane) * C;

  blur(coef, coef_blur, coef, 3 * C, H, W, w, taps);
  at::Tensor grad = at::empty_like(img);
  S* g = grad.data_ptr<S>();
  const S inv_count = static_cast<S>(1.0 / count);
  at::parallel_for(0, plane, 4096, [&](int64_t p0, int64_t p1) {
    for (int c = 0; c < C; ++c) {
      const S* k = coef + static_cast<int64_t>(3 * c) * plane;
      for (int64_t p = p0; p < p1; ++p) {
        const S x = xi[p * C + c], y = yi[p * C + c];
        g[p * C + c] = (k[p] + 2 * x * k[plane + p] + y * k[2 * plane + p]) * inv_count;
      }
    }
  });
  at::Tensor mean = at::full({}, total / count, img.options());
  return {mean, grad};
}

// -> (mean SSIM, d mean / d img), for img and target [H, W, C] of one float dtype.
std::tuple<at::Tensor, at::Tensor> ssim_forward_backward(const at::Tensor& img, const at::Tensor& target,
                                                         const at::Tensor& window, double c1, double c2) {
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
  if (img.scalar_type() == at::kDouble) return ssim_impl<double>(img, target, window, c1, c2);
  return ssim_impl<float>(img, target, window, c1, c2);
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(gsgs_raster_cpu, m) {
  m.def("ssim_forward_backward(Tensor img, Tensor target, Tensor window, float c1, float c2) -> (Tensor, Tensor)",
        &ssim_forward_backward);
}
