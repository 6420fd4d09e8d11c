// gsgs compiled binocular term: the shifted view warped into the training view along x (rectified stereo) and its
// masked L1 against the training photo, with the gradients for the shifted image and the training view's z-depth,
// in one call (gsgs_engine/train/techniques/binocular.py, `binocular_l1`).
//
// Semantics are those of the torch form there (warp_shifted_to_view + masked_l1): a training pixel (x, y) at z-depth z
// samples the shifted image at
//   ix = sfx ((x + 0.5 - cx) / fx - b / z) + scx - 0.5,   iy = sfy (y + 0.5 - cy) / fy + scy - 0.5
// (pixel centres; grid_sample's bilinear sampling with align_corners=False and border padding: coordinates clamped to
// [0, W - 1] with no gradient where clamped, taps outside the image read 0). A pixel takes part (the mask) where
// z > 1e-6, its sample point lies within the shifted image's outer pixel edges (0 <= ix + 0.5 <= W, likewise y) and
// the training render's alpha exceeds `min_alpha`. The value is sum over mask and channels of |sample - target| over
// H W C (the mean over all pixels); d|d|/dd is sign(d) (0 at 0, as torch's abs). The gradient reaches the shifted
// image through the bilinear taps and z through ix: d ix / dz = sfx b / z^2.
// Rows are split over ATen's threads for the samples and z's gradient; the loss is summed per row in double, then
// over rows in order; the taps' gradients are added into the image in two passes over groups of output rows that
// share a top tap row (even tap rows, then odd: the groups of one pass touch disjoint rows), each group in row order,
// so the result does not depend on the thread count.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include "hot.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <tuple>
#include <vector>

namespace {

struct WarpX {
  int H, W, C;       // training view (and target) size, channels
  int HS, WS;        // shifted image size
  float fx, cx, sfx, scx, b, min_alpha;
  const float* img;  // [HS, WS, C]
  const float* z;    // [H, W]
  const float* target;
  const float* alpha;
  const float* xc;   // [W]: (x + 0.5 - cx) / fx
  float inv_n;       // 1 / (H W C): each |d|'s gradient magnitude
};

// One sample's clamped coordinates and whether the x coordinate was clamped (no gradient then).
struct Tap {
  float ix, iy;
  int x0, y0;
  bool x_free;
};

inline Tap make_tap(float ix_raw, float iy_raw, int WS, int HS) {
  Tap t;
  t.x_free = ix_raw >= 0.0f && ix_raw <= static_cast<float>(WS - 1);
  t.ix = std::min(std::max(ix_raw, 0.0f), static_cast<float>(WS - 1));
  t.iy = std::min(std::max(iy_raw, 0.0f), static_cast<float>(HS - 1));
  t.x0 = static_cast<int>(std::floor(t.ix));
  t.y0 = static_cast<int>(std::floor(t.iy));
  return t;
}

// Row y: samples, loss, sign gradients (kept for the scatter) and z's gradient. Returns the row's sum of |d|.
GSGS_HOT double warp_row(const WarpX& k, int y, float iy_raw, float* gout, float* tx, int32_t* x0s, uint8_t* mask,
                         float* gz) {
  double sum[4] = {0.0, 0.0, 0.0, 0.0};
  const float ylo = -0.5f, yhi = static_cast<float>(k.HS) - 0.5f;
  const bool row_in = iy_raw >= ylo && iy_raw <= yhi;
  const Tap base = make_tap(0.0f, iy_raw, k.WS, k.HS);
  const float wy1 = base.iy - static_cast<float>(base.y0), wy0 = 1.0f - wy1;
  const bool has_y1 = base.y0 + 1 < k.HS;
  const float* r0 = k.img + static_cast<int64_t>(base.y0) * k.WS * k.C;
  const float* r1 = r0 + static_cast<int64_t>(k.WS) * k.C;
  for (int x = 0; x < k.W; ++x) {
    const int64_t p = static_cast<int64_t>(y) * k.W + x;
    gz[p] = 0.0f;
    mask[p] = 0;
    const float z = k.z[p];
    if (!row_in || !(z > 1e-6f) || !(k.alpha[p] > k.min_alpha)) continue;
    const float ix_raw = k.sfx * (k.xc[x] - k.b / z) + k.scx - 0.5f;
    if (!(ix_raw >= -0.5f && ix_raw <= static_cast<float>(k.WS) - 0.5f)) continue;  // NaN fails too
    mask[p] = 1;
    const Tap t = make_tap(ix_raw, iy_raw, k.WS, k.HS);
    const float wx1 = t.ix - static_cast<float>(t.x0), wx0 = 1.0f - wx1;
    const bool has_x1 = t.x0 + 1 < k.WS;
    float gix = 0.0f;
    for (int c = 0; c < k.C; ++c) {
      const float v00 = r0[t.x0 * k.C + c];
      const float v10 = has_x1 ? r0[(t.x0 + 1) * k.C + c] : 0.0f;
      const float v01 = has_y1 ? r1[t.x0 * k.C + c] : 0.0f;
      const float v11 = has_y1 && has_x1 ? r1[(t.x0 + 1) * k.C + c] : 0.0f;
      const float s = wy0 * (wx0 * v00 + wx1 * v10) + wy1 * (wx0 * v01 + wx1 * v11);
      const float d = s - k.target[p * k.C + c];
      sum[c & 3] += static_cast<double>(std::fabs(d));  // four chains: the double adds do not wait on each other
      // sign(d) / n without a branch (the sign of a residual is as good as random)
      const float g = static_cast<float>(d > 0.0f) * k.inv_n - static_cast<float>(d < 0.0f) * k.inv_n;
      gout[p * k.C + c] = g;
      gix += g * (wy0 * (v10 - v00) + wy1 * (v11 - v01));
    }
    tx[p] = wx1;
    x0s[p] = t.x0;
    if (t.x_free) gz[p] = gix * k.sfx * k.b / (z * z);
  }
  return (sum[0] + sum[1]) + (sum[2] + sum[3]);
}

// The taps' gradients of output row y added into the image gradient (rows y0 and y0 + 1 of it).
GSGS_HOT void scatter_row(const WarpX& k, int y, float iy_raw, const float* gout, const float* tx, const int32_t* x0s,
                          const uint8_t* mask, float* gimg) {
  const Tap base = make_tap(0.0f, iy_raw, k.WS, k.HS);
  const float wy1 = base.iy - static_cast<float>(base.y0), wy0 = 1.0f - wy1;
  const bool has_y1 = base.y0 + 1 < k.HS;
  float* r0 = gimg + static_cast<int64_t>(base.y0) * k.WS * k.C;
  float* r1 = r0 + static_cast<int64_t>(k.WS) * k.C;
  for (int x = 0; x < k.W; ++x) {
    const int64_t p = static_cast<int64_t>(y) * k.W + x;
    if (!mask[p]) continue;
    const int x0 = x0s[p];
    const float wx1 = tx[p], wx0 = 1.0f - wx1;
    const bool has_x1 = x0 + 1 < k.WS;
    for (int c = 0; c < k.C; ++c) {
      const float g = gout[p * k.C + c];
      if (g == 0.0f) continue;
      r0[x0 * k.C + c] += g * wy0 * wx0;
      if (has_x1) r0[(x0 + 1) * k.C + c] += g * wy0 * wx1;
      if (has_y1) {
        r1[x0 * k.C + c] += g * wy1 * wx0;
        if (has_x1) r1[(x0 + 1) * k.C + c] += g * wy1 * wx1;
      }
    }
  }
}

// -> (loss, d loss / d image, d loss / d z, mask) for image [HS, WS, C], z / alpha [H, W], target [H, W, C], all float32.
std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor> binocular_l1(
    const at::Tensor& image, const at::Tensor& z, const at::Tensor& target, const at::Tensor& alpha, double fx, double cx,
    double fy, double cy, double sfx, double scx, double sfy, double scy, double baseline, double min_alpha) {
  for (const at::Tensor* t : {&image, &z, &target, &alpha}) {
    TORCH_CHECK(t->device().is_cpu() && t->scalar_type() == at::kFloat && t->is_contiguous(),
                "binocular_l1: contiguous float32 CPU tensors only");
  }
  TORCH_CHECK(image.dim() == 3 && target.dim() == 3 && z.dim() == 2 && alpha.sizes() == z.sizes() &&
                  target.size(0) == z.size(0) && target.size(1) == z.size(1) && target.size(2) == image.size(2),
              "binocular_l1: image [HS, WS, C], target [H, W, C], z and alpha [H, W]; got ", image.sizes(), ", ",
              target.sizes(), ", ", z.sizes(), ", ", alpha.sizes());
  TORCH_CHECK(image.size(0) > 0 && image.size(1) > 0 && z.numel() > 0 && image.size(2) > 0, "binocular_l1: empty image");
  TORCH_CHECK(fx != 0.0 && fy != 0.0, "binocular_l1: focal lengths must be non-zero");
  WarpX k{static_cast<int>(z.size(0)), static_cast<int>(z.size(1)), static_cast<int>(image.size(2)),
          static_cast<int>(image.size(0)), static_cast<int>(image.size(1)),
          static_cast<float>(fx), static_cast<float>(cx), static_cast<float>(sfx), static_cast<float>(scx),
          static_cast<float>(baseline), static_cast<float>(min_alpha),
          image.data_ptr<float>(), z.data_ptr<float>(), target.data_ptr<float>(), alpha.data_ptr<float>(), nullptr,
          static_cast<float>(1.0 / (static_cast<double>(z.numel()) * image.size(2)))};
  std::vector<float> xc(k.W);
  for (int x = 0; x < k.W; ++x) xc[x] = static_cast<float>((x + 0.5 - cx) / fx);
  k.xc = xc.data();
  std::vector<float> iy(k.H);
  for (int y = 0; y < k.H; ++y)
    iy[y] = static_cast<float>(sfy * ((y + 0.5 - cy) / fy) + scy - 0.5);

  at::Tensor gz = at::empty_like(z);
  at::Tensor mask = at::empty(z.sizes(), z.options().dtype(at::kBool));
  at::Tensor gout = at::empty_like(target);
  at::Tensor tx = at::empty_like(z);
  std::vector<int32_t> x0s(static_cast<size_t>(z.numel()));
  std::vector<double> row_sum(k.H, 0.0);
  float* gz_p = gz.data_ptr<float>();
  uint8_t* mask_p = reinterpret_cast<uint8_t*>(mask.data_ptr<bool>());
  float* gout_p = gout.data_ptr<float>();
  float* tx_p = tx.data_ptr<float>();
  at::parallel_for(0, k.H, 8, [&](int64_t y0, int64_t y1) {
    for (int64_t y = y0; y < y1; ++y)
      row_sum[y] = warp_row(k, static_cast<int>(y), iy[y], gout_p, tx_p, x0s.data(), mask_p, gz_p);
  });
  double total = 0.0;
  for (double v : row_sum) total += v;

  // Output rows grouped by their top tap row (iy is monotonic in y, so each group is a run of rows).
  at::Tensor gimg = at::zeros_like(image);
  float* gimg_p = gimg.data_ptr<float>();
  std::vector<int> starts;  // first row of each group
  for (int y = 0; y < k.H; ++y) {
    if (y == 0 || make_tap(0.0f, iy[y], k.WS, k.HS).y0 != make_tap(0.0f, iy[y - 1], k.WS, k.HS).y0) starts.push_back(y);
  }
  starts.push_back(k.H);
  const int groups = static_cast<int>(starts.size()) - 1;
  for (int parity = 0; parity < 2; ++parity) {
    std::vector<int> mine;
    for (int g = 0; g < groups; ++g)
      if ((make_tap(0.0f, iy[starts[g]], k.WS, k.HS).y0 & 1) == parity) mine.push_back(g);
    at::parallel_for(0, static_cast<int64_t>(mine.size()), 4, [&](int64_t g0, int64_t g1) {
      for (int64_t j = g0; j < g1; ++j)
        for (int y = starts[mine[j]]; y < starts[mine[j] + 1]; ++y)
          scatter_row(k, y, iy[y], gout_p, tx_p, x0s.data(), mask_p, gimg_p);
    });
  }
  at::Tensor loss = at::full({}, total / (static_cast<double>(z.numel()) * k.C), z.options());
  return {loss, gimg, gz, mask};
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(gsgs_raster_cpu, m) {
  m.def("binocular_l1(Tensor image, Tensor z, Tensor target, Tensor alpha, float fx, float cx, float fy, float cy, "
        "float sfx, float scx, float sfy, float scy, float baseline, float min_alpha) -> (Tensor, Tensor, Tensor, Tensor)",
        &binocular_l1);
}
