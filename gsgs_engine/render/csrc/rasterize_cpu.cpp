// gsgs compiled CPU rasteriser: 3DGS tile rasterisation (forward and hand-written backward).
//
// Semantics are those of gsgs_engine/render/reference.py (see DESIGN / the module docstring of
// cpu_backend.py): 16x16 tiles, a Gaussian contributes only to the tiles its radius touches, per-pixel
// front-to-back compositing in (depth, index) order with alpha = min(0.99, o * exp(power)), skips for
// power > 0 and alpha < 1/255, and the stop rule T * (1 - alpha) < 1e-4 (that Gaussian not added).
//
// Layout of the work:
//   * visible Gaussians are sorted once by (depth, index) with a stable radix sort; tile lists then hold
//     sorted ranks, so binning in rank order yields depth-sorted tile lists without a per-tile sort; a
//     Gaussian is listed only in the tiles its alpha >= 1/255 ellipse reaches (box, then row spans), which
//     leaves out only tiles it adds nothing to;
//   * each tile is rendered Gaussian-major: for every Gaussian, the 8-pixel lane vectors its alpha
//     ellipse can reach are updated with branch-free 8-lane vector code (a polynomial exp, no libm): 4 x 2-pixel
//     blocks in the forward (fewer steps on small splats), 8 x 1 row segments in the backward (its dy moments
//     are taken once a row); each pixel is blended by the same operations either way;
//   * the backward pass walks each tile's list back to front, reconstructing T per pixel as 3DGS's CUDA
//     backward does, and writes one gradient record per (tile, Gaussian) entry; records are then summed
//     per Gaussian in a fixed order, so results are deterministic for any thread count.
// Threads come from ATen's pool (at::parallel_for: OpenMP in the PyTorch wheels, sized by
// torch.get_num_threads(), so no second OpenMP runtime is linked); tiles are handed out dynamically,
// largest first.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include "hot.h"
#include "phase_timer.h"
#include "reusable_buffer.h"

#include <algorithm>
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#include <immintrin.h>
#endif
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <numeric>
#include <tuple>
#include <vector>

namespace {

constexpr int kTile = 16;
constexpr int kTilePixels = kTile * kTile;
constexpr float kMinAlpha = 1.0f / 255.0f;
constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 1e-4f;
const double kLogMinAlpha = std::log(static_cast<double>(kMinAlpha));
const double kLog255 = std::log(255.0);
constexpr int kGradFields = 10;  // mx, my, A, B, C, r, g, b, opacity, depth
constexpr int kSplatFloats = 13;  // a Splat record, as the float32 tensor [n_vis, 13] the forward hands the backward

#define GSGS_INLINE inline __attribute__((always_inline))
// Vector helpers are always inlined, so their 32-byte arguments never cross a call boundary.
#pragma GCC diagnostic ignored "-Wpsabi"

// One visible Gaussian, in depth order, everything the tile loops read (one 52-byte record).
struct Splat {
  float mx, my;     // means2d (pixel coordinates)
  float A, B, C;    // conic (inverse 2D covariance)
  float opacity;
  float r, g, b;
  float depth;
  float ext_x, ext_y;  // half-extent of the region where alpha >= 1/255 (+margin); < 0: never
  float power_floor;   // exponent below which alpha < 1/255 (power_floor())
};

static_assert(sizeof(Splat) == kSplatFloats * sizeof(float), "Splat is a record of floats (kept as a tensor)");

// Eight float lanes (GCC/Clang vector extensions): one AVX register in the AVX2 clone, two SSE
// registers in the portable one. Explicit vectors, because GCC leaves the masked lane loops scalar.
typedef float vf __attribute__((vector_size(32), aligned(32)));
typedef int32_t vi __attribute__((vector_size(32), aligned(32)));
constexpr int kLanes = 8;
constexpr int kVecPerRow = kTile / kLanes;
constexpr int kVecs = kTilePixels / kLanes;

GSGS_INLINE vf splat(float v) { return vf{} + v; }
GSGS_INLINE vi splat_i(int32_t v) { return vi{} + v; }
GSGS_INLINE vf select(vi mask, vf a, vf b) { return (vf)(((vi)a & mask) | ((vi)b & ~mask)); }
GSGS_INLINE vf vabs(vf a) { return (vf)((vi)a & splat_i(0x7fffffff)); }
GSGS_INLINE vi select_i(vi mask, vi a, vi b) { return (a & mask) | (b & ~mask); }
GSGS_INLINE bool any(vi mask) {
  uint64_t q[4];
  std::memcpy(q, &mask, sizeof q);
  return (q[0] | q[1] | q[2] | q[3]) != 0;
}
GSGS_INLINE float hsum(vf v) {
  float s = 0.0f;
  for (int i = 0; i < kLanes; ++i) s += v[i];
  return s;
}
// Lane sums of eight vectors at once -> out[0..7]: three shuffle-and-add levels instead of 8 x 7 scalar adds.
#if defined(__clang__)  // clang spells the two-vector shuffle with constant indices
#define GSGS_SHUFFLE(x, y, i0, i1, i2, i3, i4, i5, i6, i7) __builtin_shufflevector(x, y, i0, i1, i2, i3, i4, i5, i6, i7)
#else
#define GSGS_SHUFFLE(x, y, i0, i1, i2, i3, i4, i5, i6, i7) __builtin_shuffle(x, y, vi{i0, i1, i2, i3, i4, i5, i6, i7})
#endif
GSGS_INLINE void hsum8(const vf* a, float* out) {
  vf p[4], q[2];
  for (int i = 0; i < 4; ++i)
    p[i] = GSGS_SHUFFLE(a[2 * i], a[2 * i + 1], 0, 8, 2, 10, 4, 12, 6, 14) +
           GSGS_SHUFFLE(a[2 * i], a[2 * i + 1], 1, 9, 3, 11, 5, 13, 7, 15);
  for (int i = 0; i < 2; ++i)
    q[i] = GSGS_SHUFFLE(p[2 * i], p[2 * i + 1], 0, 1, 8, 9, 4, 5, 12, 13) +
           GSGS_SHUFFLE(p[2 * i], p[2 * i + 1], 2, 3, 10, 11, 6, 7, 14, 15);
  const vf r = GSGS_SHUFFLE(q[0], q[1], 0, 1, 2, 3, 8, 9, 10, 11) + GSGS_SHUFFLE(q[0], q[1], 4, 5, 6, 7, 12, 13, 14, 15);
  std::memcpy(out, &r, sizeof r);
}

// exp(x) for the alpha test, for x already clamped to [-87, 0] (exp_nonpositive in tile_bodies.h: NaN -> -87):
// Cephes' expf polynomial with round-to-nearest range reduction, ~1 ulp, exp(0) == 1 exactly. libm's expf cannot
// be vectorised without -ffast-math.
GSGS_INLINE vf exp_mantissa(vf x, vf* n_out) {  // exp(x) = mantissa * 2^n, n = round(x / ln 2) in [-126, 0]
  const vf t = x * 1.44269504088896341f;
  const vf n = (t + 12582912.0f) - 12582912.0f;  // round(t): 1.5 * 2^23 shifts out the fraction
  vf r = x - n * 0.693359375f;
  r = r - n * -2.12194440e-4f;
  vf p = splat(1.9875691500e-4f);
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  *n_out = n;
  return p * r * r + r + 1.0f;
}
GSGS_INLINE vf exp_clamped(vf x) {
  vf n;
  const vf y = exp_mantissa(x, &n);
  const vi e = __builtin_convertvector(n, vi) + 127;  // n in [-126, 0]: a normal power of two
  return y * (vf)(e << 23);
}

// The Gaussian exponent -(A dx^2 + C dy^2) / 2 - B dx dy, with what depends on the 8-pixel column alone (dx per
// lane, A dx, B dx) made once per Gaussian and column and the row's C dy^2 once per row: the same expression tree
// as evaluating it whole (so the same rounding, and exactly 0 along a needle where A = C = -B), three vector
// operations a step instead of six. Forward and backward share these functions, so both take the same skip
// decisions bit for bit.
struct ColumnTerms {
  vf dx, a_dx, b_dx;
};
GSGS_INLINE ColumnTerms column_terms(const Splat& s, vf px) {
  const vf dx = s.mx - px;
  return ColumnTerms{dx, s.A * dx, s.B * dx};
}
// dy is one float for an 8 x 1 row segment (the backward) and a lane vector for a 4 x 2 block (the forward): the same
// expression tree either way, so a pixel's exponent is the same value in both passes.
template <typename D>
GSGS_INLINE D row_term(const Splat& s, D dy) { return s.C * dy * dy; }
template <typename D>
GSGS_INLINE vf gaussian_power(const ColumnTerms& col, D dy, D c_dy2) {
  return -0.5f * (col.a_dx * col.dx + c_dy2) - col.b_dx * dy;
}

// The exponent below which no lane can reach alpha >= 1/255: o * exp(power) < 1/255 for power < ln(1 / (255 o)).
// A millesimal margin in the exponent covers the rounding of exp_nonpositive (~1 ulp), so an 8-pixel step whose
// powers all lie below it changes nothing in either pass and is skipped before its exp is evaluated: results are
// bit-identical to evaluating it. (Opacities below 1/255 never reach a tile: their alpha extent is empty.)
GSGS_INLINE float power_floor(double log_opacity) {
  return static_cast<float>(kLogMinAlpha - log_opacity) - 1e-3f;
}

// Row (or column) index range [lo, hi] inside a tile starting at pixel `start` whose centres lie
// within `ext` of `centre`; lo > hi when none does. Pixel centres are at start + i + 0.5.
GSGS_INLINE void lane_range(float centre, float ext, int start, int count, int* lo, int* hi) {
  const float a = centre - ext - 0.5f - static_cast<float>(start);
  const float b = centre + ext - 0.5f - static_cast<float>(start);
  // Compare in float before converting: ext may be +inf.
  *lo = !(a > 0.0f) ? 0 : (a >= static_cast<float>(count) ? count : static_cast<int>(std::ceil(a)));
  *hi = !(b < static_cast<float>(count - 1)) ? count - 1 : (b < 0.0f ? -1 : static_cast<int>(std::floor(b)));
}

// Half-extents of the ellipse o * exp(-q/2) >= 1/255, q = d^T conic d, i.e. q <= 2 ln(255 o); its
// x half-width is sqrt(k * Sigma_xx) with Sigma = conic^-1. Pixels outside cannot pass the alpha
// test, so restricting the loops to it changes no result; the margin covers float rounding.
GSGS_INLINE void alpha_extent(float A, float B, float C, double log_opacity, float* ext_x, float* ext_y) {
  const double a = A, b = B, c = C;
  const double det = a * c - b * b;
  if (!(a > 0.0 && c > 0.0 && det > 0.0 && std::isfinite(det))) {
    // Not positive definite: no bound, evaluate the whole tile like the reference does.
    *ext_x = *ext_y = std::numeric_limits<float>::infinity();
    return;
  }
  const double k_over_det = std::max(0.0, 2.0 * (kLog255 + log_opacity)) / det;  // one division for both
  *ext_x = static_cast<float>(std::sqrt(c * k_over_det) * 1.001 + 1.0);
  *ext_y = static_cast<float>(std::sqrt(a * k_over_det) * 1.001 + 1.0);
}

// A splat's alpha >= 1/255 bounds (alpha_extent, power_floor) from one logarithm of its opacity. alpha =
// min(0.99, o G) with G <= 1, so o < 1/255 can never pass (NaN neither): an empty extent, an infinite floor.
GSGS_INLINE void alpha_bounds(Splat& sp) {
  if (!(sp.opacity >= kMinAlpha)) {
    sp.ext_x = sp.ext_y = -1.0f;
    sp.power_floor = std::numeric_limits<float>::infinity();
    return;
  }
  // logf: its error (~1e-7) is far inside the margins both bounds carry
  const double log_opacity = std::log(sp.opacity);
  alpha_extent(sp.A, sp.B, sp.C, log_opacity, &sp.ext_x, &sp.ext_y);
  sp.power_floor = power_floor(log_opacity);
}

// Depth -> unsigned key with the same order as the float (negative values flipped); -0 == +0 and
// every NaN sorts last, as in torch.sort.
GSGS_INLINE uint32_t depth_key(float d) {
  if (std::isnan(d)) return 0xFFFFFFFFu;
  if (d == 0.0f) d = 0.0f;
  uint32_t u;
  std::memcpy(&u, &d, sizeof u);
  return (u & 0x80000000u) ? ~u : (u | 0x80000000u);
}

// Stable LSD radix sort of `ids` by `keys` (both permuted together); passes whose byte is constant
// are skipped.
void radix_sort_by_key(std::vector<uint32_t>& keys, std::vector<int32_t>& ids) {
  const size_t n = keys.size();
  std::vector<uint32_t> keys_tmp(n);
  std::vector<int32_t> ids_tmp(n);
  for (int shift = 0; shift < 32; shift += 8) {
    size_t count[257] = {0};
    for (size_t i = 0; i < n; ++i) ++count[((keys[i] >> shift) & 0xFFu) + 1];
    bool constant = false;
    for (int bucket = 1; bucket <= 256; ++bucket) {
      if (count[bucket] == n) constant = true;
    }
    if (constant) continue;
    for (int bucket = 0; bucket < 256; ++bucket) count[bucket + 1] += count[bucket];
    for (size_t i = 0; i < n; ++i) {
      const size_t dst = count[(keys[i] >> shift) & 0xFFu]++;
      keys_tmp[dst] = keys[i];
      ids_tmp[dst] = ids[i];
    }
    keys.swap(keys_tmp);
    ids.swap(ids_tmp);
  }
}

using gsgs_scratch::reusable_buffer;

struct TileRect {
  int x0, x1, y0, y1;  // inclusive tile index range
};

// Tiles touched by a Gaussian: [floor((m - r) / 16), floor((m + r) / 16)] clipped to the grid. In
// double, as the reference bins: float32 m + r can round up onto a tile boundary.
GSGS_INLINE bool tile_rect(float mx, float my, int radius, int tiles_x, int tiles_y, TileRect* rect) {
  if (radius <= 0 || !std::isfinite(mx) || !std::isfinite(my)) return false;
  const double r = static_cast<double>(radius), x = mx, y = my;
  const double x0 = std::max(std::floor((x - r) / kTile), 0.0);
  const double x1 = std::min(std::floor((x + r) / kTile), static_cast<double>(tiles_x - 1));
  const double y0 = std::max(std::floor((y - r) / kTile), 0.0);
  const double y1 = std::min(std::floor((y + r) / kTile), static_cast<double>(tiles_y - 1));
  if (!(x0 <= x1 && y0 <= y1)) return false;
  rect->x0 = static_cast<int>(x0);
  rect->x1 = static_cast<int>(x1);
  rect->y0 = static_cast<int>(y0);
  rect->y1 = static_cast<int>(y1);
  return true;
}

// The tiles of `rect` (the 3-sigma square binning) that the alpha >= 1/255 box of `s` also reaches. A tile
// outside that box gets nothing from `s`, so leaving it out of the lists changes no result; on trained LLFF
// models it drops about 40 % of the entries (less memory for the lists and the backward's records). An
// empty rectangle (x1 < x0) when none is left.
GSGS_INLINE void clip_to_alpha_extent(const Splat& s, TileRect* rect) {
  if (!(s.ext_x >= 0.0f)) {
    *rect = TileRect{0, -1, 0, -1};
    return;
  }
  if (!(s.ext_x < std::numeric_limits<float>::infinity() && s.ext_y < std::numeric_limits<float>::infinity())) return;
  // pixel centres within ext of the mean: indices in [m - ext - 0.5, m + ext - 0.5]
  const double x0 = std::floor((static_cast<double>(s.mx) - s.ext_x - 0.5) / kTile);
  const double x1 = std::floor((static_cast<double>(s.mx) + s.ext_x - 0.5) / kTile);
  const double y0 = std::floor((static_cast<double>(s.my) - s.ext_y - 0.5) / kTile);
  const double y1 = std::floor((static_cast<double>(s.my) + s.ext_y - 0.5) / kTile);
  rect->x0 = static_cast<int>(std::max<double>(rect->x0, x0));
  rect->x1 = static_cast<int>(std::min<double>(rect->x1, x1));
  rect->y0 = static_cast<int>(std::max<double>(rect->y0, y0));
  rect->y1 = static_cast<int>(std::min<double>(rect->y1, y1));
  if (rect->x0 > rect->x1 || rect->y0 > rect->y1) *rect = TileRect{0, -1, 0, -1};
}

// The tiles of one row of `rect` that the alpha >= 1/255 ellipse of `s` reaches: *x0..*x1 (empty: *x1 < *x0).
// Over the row's band of pixel-centre offsets dy = my - yc, the ellipse's pixel centres x lie in
// mx + [min (B dy - sqrt(D)), max (B dy + sqrt(D))] / A, D = A K - det dy^2, K = -2 power_floor (power >= floor
// <=> q = A dx^2 + 2 B dx dy + C dy^2 <= K); the concave max is taken at dy = B sqrt(K / (C det)) clamped to the
// band, the convex min at its mirror. K is widened by 0.1 % and the span by a pixel against the kernel's float
// rounding, so a tile left out can never pass the kernel's own floor test: dropping it changes no result. On trained
// models (3x3-tile rectangles and up culled) this drops 22 % of flower's entries and 3 % of lego's.
// Conics that are not positive definite, and unbounded extents, keep the whole row.
struct EllipseRows {
  bool bounded;  // a positive definite conic with a finite extent; otherwise every row keeps the rectangle's tiles
  double mx, my, b, inv_a, a_k, det, y_half, t;
};
GSGS_INLINE EllipseRows ellipse_rows(const Splat& s) {
  const double A = s.A, B = s.B, C = s.C;
  const double det = A * C - B * B;
  const double K = -2.0 * static_cast<double>(s.power_floor) * 1.001 + 1e-3;
  EllipseRows e{false, s.mx, s.my, B, 0.0, 0.0, det, 0.0, 0.0};
  if (!(A > 0.0 && C > 0.0 && det > 0.0 && std::isfinite(det) && K > 0.0 && std::isfinite(K) &&
        s.ext_x < std::numeric_limits<float>::infinity() && s.ext_y < std::numeric_limits<float>::infinity()))
    return e;
  e.bounded = true;
  e.inv_a = 1.0 / A;
  e.a_k = A * K;
  e.y_half = std::sqrt(e.a_k / det);
  e.t = std::sqrt(K / (C * det));
  return e;
}
GSGS_INLINE void tile_row_span(const EllipseRows& e, const TileRect& rect, int ty, int* x0, int* x1) {
  *x0 = rect.x0;
  *x1 = rect.x1;
  if (!e.bounded) return;
  const double band_lo = e.my - (static_cast<double>(ty) * kTile + (kTile - 0.5));
  const double band_hi = e.my - (static_cast<double>(ty) * kTile + 0.5);
  const double a = std::max(band_lo, -e.y_half), b = std::min(band_hi, e.y_half);
  if (!(a <= b)) {
    *x0 = 0;
    *x1 = -1;
    return;
  }
  const double dy_right = std::clamp(e.b * e.t, a, b), dy_left = std::clamp(-e.b * e.t, a, b);
  const double right = e.b * dy_right + std::sqrt(std::max(0.0, e.a_k - e.det * dy_right * dy_right));
  const double left = e.b * dy_left - std::sqrt(std::max(0.0, e.a_k - e.det * dy_left * dy_left));
  // pixel centre c lies in tile floor((c - 0.5) / 16); clamped to the rectangle (whose indices are >= 0) before the
  // conversion, where truncation is the floor
  const double lo = (e.mx + left * e.inv_a - 1.5) * (1.0 / kTile), hi = (e.mx + right * e.inv_a + 0.5) * (1.0 / kTile);
  if (hi < 0.0) {
    *x0 = 0;
    *x1 = -1;
    return;
  }
  *x0 = static_cast<int>(std::max<double>(rect.x0, std::min<double>(rect.x1 + 1, lo)));
  *x1 = static_cast<int>(std::min<double>(rect.x1, hi));
}

struct RowSpan {
  int32_t x0, x1;
};

// Ranks [s0, s1): each rectangle with rows in `spans` (span_offset[s] < span_offset[s + 1]) culled row by row,
// and every rank's entry count. A named function, so the processor's AVX2 clone (GSGS_HOT) runs it.
GSGS_HOT void cull_rows(const Splat* splats, const TileRect* rects, const int64_t* span_offset, RowSpan* spans,
                        int32_t* entries_of, int64_t s0, int64_t s1) {
  for (int64_t s = s0; s < s1; ++s) {
    const TileRect& r = rects[s];
    if (span_offset[s + 1] == span_offset[s]) {
      entries_of[s] = std::max(0, r.x1 - r.x0 + 1) * std::max(0, r.y1 - r.y0 + 1);
      continue;
    }
    const EllipseRows e = ellipse_rows(splats[s]);
    int32_t n_entries = 0;
    for (int ty = r.y0; ty <= r.y1; ++ty) {
      RowSpan& row = spans[span_offset[s] + (ty - r.y0)];
      tile_row_span(e, r, ty, &row.x0, &row.x1);
      n_entries += std::max(0, row.x1 - row.x0 + 1);
    }
    entries_of[s] = n_entries;
  }
}

// Runs fn(tile) for every tile of `order` on ATen's threads, handing tiles out one at a time.
template <typename Fn>
void for_each_tile(const std::vector<int32_t>& order, Fn&& fn) {
  std::atomic<int64_t> next{0};
  const int64_t n = static_cast<int64_t>(order.size());
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n));
  at::parallel_for(0, workers, 1, [&](int64_t, int64_t) {
    for (int64_t i = next.fetch_add(1); i < n; i = next.fetch_add(1)) fn(order[i]);
  });
}

// ---------------------------------------------------------------------------------------------
// Lane vectors of the pixel-centre x coordinates of a tile row.
GSGS_INLINE void pixel_centres(int px0, vf* out) {
  for (int v = 0; v < kVecPerRow; ++v)
    for (int i = 0; i < kLanes; ++i) out[v][i] = static_cast<float>(px0 + v * kLanes + i) + 0.5f;
}

// Pixel columns [c_lo, c_hi] and rows [r_lo, r_hi] of the tile a Gaussian can reach; false when none.
GSGS_INLINE bool reach_pixels(const Splat& s, int px0, int py0, int cols, int rows, int* c_lo, int* c_hi, int* r_lo,
                              int* r_hi) {
  if (s.ext_x < 0.0f) return false;
  lane_range(s.mx, s.ext_x, px0, cols, c_lo, c_hi);
  if (*c_lo > *c_hi) return false;
  lane_range(s.my, s.ext_y, py0, rows, r_lo, r_hi);
  return *r_lo <= *r_hi;
}

// Rows and 8 x 1 lane vectors of the tile a Gaussian can reach (empty: r_lo > r_hi).
GSGS_INLINE void reach(const Splat& s, int px0, int py0, int cols, int rows, int* r_lo, int* r_hi, int* v_lo,
                       int* v_hi) {
  int c_lo, c_hi;
  if (!reach_pixels(s, px0, py0, cols, rows, &c_lo, &c_hi, r_lo, r_hi)) {
    *r_lo = 0;
    *r_hi = -1;
    return;
  }
  *v_lo = c_lo / kLanes;
  *v_hi = c_hi / kLanes;
}

// The tile bodies (tile_bodies.h) compiled four times: AVX-512VL (the same 8-lane code with FMA, given 32 vector
// registers and mask registers: the backward's ten accumulators no longer spill, ~1.2x on a 50k flower model,
// bit-identical to the FMA variant on the tests' scenes), AVX2 with FMA (products and sums contracted: forward and
// backward 10-20 % faster on a trained LLFF model, docs/speed.md), AVX2, and portable x86-64; picked once per
// process from the processor's features. Forward and backward of one process always use the same variant, and both
// evaluate alpha through the same inline functions (gaussian_power, exp_nonpositive), which GCC contracts
// alike in both; that is relied on, not guaranteed by the language, and the gradient parity tests against the
// reference check it. GSGS_NO_FMA=1 selects the uncontracted AVX2 variant, bit-identical to the earlier kernel.
#define GSGS_TILE_ARGS_F const Splat *splats, const int32_t *ranks, int count, int px0, int py0, int width, \
    int height, const float *background, float *out_color, float *out_depth, float *out_alpha, float *out_T, \
    int32_t *out_last
#define GSGS_TILE_ARGS_B const Splat *splats, const int32_t *ranks, const int32_t *slots, int count, int px0, \
    int py0, int width, int height, const float *background, const float *final_T, const int32_t *last_in, \
    const float *grad_color, const float *grad_depth, const float *grad_alpha, bool with_depth, float *entry_grad, \
    float *abs_grad
#define GSGS_TILE_PASS_B splats, ranks, slots, count, px0, py0, width, height, background, final_T, last_in, \
    grad_color, grad_depth, grad_alpha, with_depth, entry_grad, abs_grad
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define GSGS_TILE_AVX 1
#define GSGS_TILE_AVX512 1
#pragma GCC push_options
#pragma GCC target("avx2,fma,avx512f,avx512vl,avx512dq,avx512bw")
#pragma GCC optimize("fp-contract=fast")
namespace isa_avx512 {
#include "tile_bodies.h"
}  // namespace isa_avx512
#undef GSGS_TILE_AVX512
#define GSGS_TILE_AVX512 0
#pragma GCC pop_options
#pragma GCC push_options
#pragma GCC target("avx2,fma")
#pragma GCC optimize("fp-contract=fast")
namespace isa_fma {
#include "tile_bodies.h"
}  // namespace isa_fma
#pragma GCC pop_options
#pragma GCC push_options
#pragma GCC target("avx2")
namespace isa_avx2 {
#include "tile_bodies.h"
}  // namespace isa_avx2
#pragma GCC pop_options
#undef GSGS_TILE_AVX
#else
#define GSGS_TILE_AVX512 0
#endif
#define GSGS_TILE_AVX 0
namespace isa_portable {
#include "tile_bodies.h"
}  // namespace isa_portable

using ForwardTileFn = void (*)(GSGS_TILE_ARGS_F);
using BackwardTileFn = void (*)(GSGS_TILE_ARGS_B);
struct TileKernels {
  ForwardTileFn forward;
  BackwardTileFn backward;
};

// The best variant the processor runs, or the one named by GSGS_TILE_VARIANT=avx512|fma|avx2|portable (tests render
// with each; GSGS_NO_FMA=1 is the older spelling of avx2). A variant the processor cannot run is never chosen: the
// next one down the list is.
const TileKernels& tile_kernels() {
  static const TileKernels chosen = [] {
    const char* forced = getenv("GSGS_TILE_VARIANT");
    int ceiling = 0;  // 0 avx512, 1 fma, 2 avx2, 3 portable: the best variant allowed
    if (forced != nullptr && std::strcmp(forced, "fma") == 0) ceiling = 1;
    if (getenv("GSGS_NO_FMA") != nullptr || (forced != nullptr && std::strcmp(forced, "avx2") == 0)) ceiling = 2;
    if (forced != nullptr && std::strcmp(forced, "portable") == 0) ceiling = 3;
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
    __builtin_cpu_init();
    const bool avx2 = __builtin_cpu_supports("avx2"), fma = avx2 && __builtin_cpu_supports("fma");
    const bool avx512 = fma && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
                        __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw");
    if (ceiling <= 0 && avx512) return TileKernels{isa_avx512::forward_tile, isa_avx512::backward_tile};
    if (ceiling <= 1 && fma) return TileKernels{isa_fma::forward_tile, isa_fma::backward_tile};
    if (ceiling <= 2 && avx2) return TileKernels{isa_avx2::forward_tile, isa_avx2::backward_tile};
#else
    (void)ceiling;
#endif
    return TileKernels{isa_portable::forward_tile, isa_portable::backward_tile};
  }();
  return chosen;
}

// ---------------------------------------------------------------------------------------------
// Visible Gaussians in (depth, index) order and their per-tile lists.
struct Binning {
  std::vector<int32_t> order;        // rank -> Gaussian index
  at::Tensor splats;                 // float32 [n_vis, kSplatFloats]: the Splat records by rank
  std::vector<int32_t> slot_offset;  // rank -> first gradient slot (size n_vis + 1)
  at::Tensor tile_offsets;           // int32 [n_tiles + 1]
  at::Tensor tile_ranks;             // int32 [n_entries], depth-sorted per tile
  at::Tensor entry_slots;            // int32 [n_entries], gradient record of each entry
};

void check_inputs(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                  const at::Tensor& opacities, const at::Tensor& depths, const at::Tensor& radii,
                  int64_t width, int64_t height, const at::Tensor& background) {
  const int64_t n = means2d.size(0);
  auto check = [&](const at::Tensor& t, const char* name, at::ScalarType dtype, std::vector<int64_t> shape) {
    TORCH_CHECK(t.device().is_cpu(), "rasterize_cpu: ", name, " must be a CPU tensor");
    TORCH_CHECK(t.scalar_type() == dtype, "rasterize_cpu: ", name, " must be ", dtype, ", got ", t.scalar_type());
    TORCH_CHECK(t.is_contiguous(), "rasterize_cpu: ", name, " must be contiguous");
    TORCH_CHECK(t.sizes() == at::IntArrayRef(shape), "rasterize_cpu: ", name, " must have shape ", at::IntArrayRef(shape),
                ", got ", t.sizes());
  };
  TORCH_CHECK(means2d.dim() == 2, "rasterize_cpu: means2d must be [N, 2]");
  check(means2d, "means2d", at::kFloat, {n, 2});
  check(conics, "conics", at::kFloat, {n, 3});
  check(colors, "colors", at::kFloat, {n, 3});
  check(opacities, "opacities", at::kFloat, {n});
  check(depths, "depths", at::kFloat, {n});
  check(radii, "radii", at::kInt, {n});
  check(background, "background", at::kFloat, {3});
  TORCH_CHECK(width > 0 && height > 0 && width <= (1 << 20) && height <= (1 << 20),
              "rasterize_cpu: image size must be positive, got ", width, "x", height);
  TORCH_CHECK(n < std::numeric_limits<int32_t>::max(), "rasterize_cpu: too many Gaussians");
}

// The Splat records of a float32 [n, kSplatFloats] tensor (its storage, viewed as records).
Splat* splat_records(const at::Tensor& t) {
  return reinterpret_cast<Splat*>(t.data_ptr<float>());
}

// Gaussians [g0, g1): whether each one's 3-sigma tile rectangle reaches the image (binned) and that rectangle.
// A named function, so the processor's AVX2 clone (GSGS_HOT) runs it (floor is one instruction there).
GSGS_HOT void tile_rects(const float* m, const int32_t* rad, int tiles_x, int tiles_y, uint8_t* binned,
                         TileRect* rect_of, int64_t g0, int64_t g1) {
  for (int64_t g = g0; g < g1; ++g) binned[g] = tile_rect(m[2 * g], m[2 * g + 1], rad[g], tiles_x, tiles_y, &rect_of[g]);
}

// The per-Gaussian inputs a splat record is made of.
struct SplatInputs {
  const float *means2d, *conics, *colors, *opacities, *depths;
};

// Ranks [s0, s1): the splat record of Gaussian order[s] with its alpha bounds, and its tile rectangle clipped to
// them. The inputs are read in depth order, so each rank's are asked for kAhead ranks early (they lie anywhere in
// the arrays); the records are written in sequence. Building them in rank order instead of gathering records made
// in index order saves one pass over every record.
GSGS_HOT void gather_splats(const SplatInputs& in, const int32_t* order, const TileRect* rect_of, Splat* splats,
                            TileRect* rects, int64_t s0, int64_t s1) {
  constexpr int64_t kAhead = 16;
  for (int64_t s = s0; s < s1; ++s) {
    if (s + kAhead < s1) {
      const int64_t a = order[s + kAhead];
      __builtin_prefetch(in.means2d + 2 * a);
      __builtin_prefetch(in.conics + 3 * a);
      __builtin_prefetch(in.colors + 3 * a);
      __builtin_prefetch(in.opacities + a);
      __builtin_prefetch(in.depths + a);
      __builtin_prefetch(rect_of + a);
    }
    const int64_t g = order[s];
    Splat& sp = splats[s];
    sp = Splat{in.means2d[2 * g], in.means2d[2 * g + 1], in.conics[3 * g], in.conics[3 * g + 1], in.conics[3 * g + 2],
               in.opacities[g], in.colors[3 * g], in.colors[3 * g + 1], in.colors[3 * g + 2], in.depths[g],
               0.0f, 0.0f, 0.0f};
    alpha_bounds(sp);
    rects[s] = rect_of[g];
    clip_to_alpha_extent(sp, &rects[s]);
  }
}

Binning bin_gaussians(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                      const at::Tensor& opacities, const at::Tensor& depths, const at::Tensor& radii,
                      int tiles_x, int tiles_y) {
  const int64_t n = means2d.size(0);
  const float* m = means2d.data_ptr<float>();
  const float* cn = conics.data_ptr<float>();
  const float* col = colors.data_ptr<float>();
  const float* op = opacities.data_ptr<float>();
  const float* dp = depths.data_ptr<float>();
  const int32_t* rad = radii.data_ptr<int32_t>();
  const int n_tiles = tiles_x * tiles_y;

  Binning b;
  // Every Gaussian: whether its 3-sigma tile rectangle reaches the image (it is binned), and that rectangle, on all
  // threads (tile_rects)...
  uint8_t* const binned = reusable_buffer<uint8_t, 0>(n);
  TileRect* const rect_of = reusable_buffer<TileRect, 1>(n);
  at::parallel_for(0, n, 2048, [&](int64_t g0, int64_t g1) {
    tile_rects(m, rad, tiles_x, tiles_y, binned, rect_of, g0, g1);
  });
  // ...then the binned ones sorted by depth...
  std::vector<uint32_t> keys;
  std::vector<int32_t> ids;
  keys.reserve(n);
  ids.reserve(n);
  for (int64_t g = 0; g < n; ++g) {
    if (binned[g]) {
      keys.push_back(depth_key(dp[g]));
      ids.push_back(static_cast<int32_t>(g));
    }
  }
  radix_sort_by_key(keys, ids);
  b.order = std::move(ids);
  const int64_t n_vis = static_cast<int64_t>(b.order.size());

  // ...and their splat records built in depth order, each with its alpha >= 1/255 bounds and its rectangle clipped
  // to them (possibly empty; gather_splats). The records outlive the call: the backward composites from them.
  b.splats = at::empty({n_vis, kSplatFloats}, at::kFloat);
  Splat* const splats = splat_records(b.splats);
  TileRect* const rects = reusable_buffer<TileRect, 0>(n_vis);
  const SplatInputs in{m, cn, col, op, dp};
  at::parallel_for(0, n_vis, 2048, [&](int64_t s0, int64_t s1) {
    gather_splats(in, b.order.data(), rect_of, splats, rects, s0, s1);
  });
  // Rectangles at least three tiles each way are culled row by row to the tiles their ellipse reaches
  // (tile_row_span, in cull_rows; the spans in one buffer, span_offset[s] the first row of rank s, an empty range for
  // the others). A rectangle one tile wide or high has nothing to cull (the ellipse reaches each side of its alpha
  // box), and a 2 x N one little: measured on trained flower / lego models, the test cost about what it saved there.
  auto culled = [](const TileRect& r) {
    return r.x1 - r.x0 >= 2 && r.y1 - r.y0 >= 2;
  };
  int64_t* const span_offset = reusable_buffer<int64_t, 0>(n_vis + 1);
  span_offset[0] = 0;
  for (int64_t s = 0; s < n_vis; ++s)
    span_offset[s + 1] = span_offset[s] + (culled(rects[s]) ? rects[s].y1 - rects[s].y0 + 1 : 0);
  RowSpan* const spans = reusable_buffer<RowSpan, 0>(span_offset[n_vis]);
  int32_t* const entries_of = reusable_buffer<int32_t, 0>(n_vis);
  at::parallel_for(0, n_vis, 2048, [&](int64_t s0, int64_t s1) {
    cull_rows(splats, rects, span_offset, spans, entries_of, s0, s1);
  });
  // fn(tile index) for every tile rank s is binned to, row by row in tile order
  auto for_each_entry = [&](int64_t s, auto&& fn) {
    const TileRect& r = rects[s];
    if (span_offset[s + 1] == span_offset[s]) {
      for (int ty = r.y0; ty <= r.y1; ++ty)
        for (int tx = r.x0; tx <= r.x1; ++tx) fn(ty * tiles_x + tx);
      return;
    }
    const RowSpan* const row = spans + span_offset[s] - r.y0;
    for (int ty = r.y0; ty <= r.y1; ++ty)
      for (int tx = row[ty].x0; tx <= row[ty].x1; ++tx) fn(ty * tiles_x + tx);
  };
  b.slot_offset.assign(n_vis + 1, 0);
  int64_t total = 0;
  for (int64_t s = 0; s < n_vis; ++s) {
    b.slot_offset[s] = static_cast<int32_t>(total);
    total += entries_of[s];
    TORCH_CHECK(total < std::numeric_limits<int32_t>::max(),
                "rasterize_cpu: more than 2^31 Gaussian-tile pairs; render at a lower resolution");
  }
  b.slot_offset[n_vis] = static_cast<int32_t>(total);

  // Per-chunk tile counts, then offsets chunk after chunk inside each tile: lists stay in rank order.
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n_vis / 4096 + 1));
  const int64_t chunk_len = (n_vis + chunks - 1) / chunks;
  std::vector<int32_t> counts(static_cast<size_t>(chunks) * n_tiles, 0);
  at::parallel_for(0, chunks, 1, [&](int64_t c0, int64_t c1) {
    for (int64_t c = c0; c < c1; ++c) {
      int32_t* cnt = counts.data() + c * n_tiles;
      for (int64_t s = c * chunk_len; s < std::min(n_vis, (c + 1) * chunk_len); ++s)
        for_each_entry(s, [&](int tile) { ++cnt[tile]; });
    }
  });
  b.tile_offsets = at::empty({n_tiles + 1}, at::kInt);
  int32_t* offsets = b.tile_offsets.data_ptr<int32_t>();
  int32_t running = 0;
  for (int t = 0; t < n_tiles; ++t) {
    offsets[t] = running;
    for (int64_t c = 0; c < chunks; ++c) {
      const int32_t k = counts[c * n_tiles + t];
      counts[c * n_tiles + t] = running;  // becomes this chunk's cursor in tile t
      running += k;
    }
  }
  offsets[n_tiles] = running;
  b.tile_ranks = at::empty({static_cast<int64_t>(running)}, at::kInt);
  b.entry_slots = at::empty({static_cast<int64_t>(running)}, at::kInt);
  int32_t* tile_ranks = b.tile_ranks.data_ptr<int32_t>();
  int32_t* entry_slots = b.entry_slots.data_ptr<int32_t>();
  at::parallel_for(0, chunks, 1, [&](int64_t c0, int64_t c1) {
    for (int64_t c = c0; c < c1; ++c) {
      int32_t* cursor = counts.data() + c * n_tiles;
      for (int64_t s = c * chunk_len; s < std::min(n_vis, (c + 1) * chunk_len); ++s) {
        int32_t slot = b.slot_offset[s];
        for_each_entry(s, [&](int tile) {
          const int32_t e = cursor[tile]++;
          tile_ranks[e] = static_cast<int32_t>(s);
          entry_slots[e] = slot++;
        });
      }
    }
  });
  return b;
}

// Tiles, most entries first, so the long ones do not finish last on one thread.
std::vector<int32_t> tile_schedule(const int32_t* offsets, int n_tiles) {
  std::vector<int32_t> order(n_tiles);
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int32_t a, int32_t b) {
    return offsets[a + 1] - offsets[a] > offsets[b + 1] - offsets[b];
  });
  return order;
}

using ForwardResult = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor,
                                 at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

// -> color [H,W,3], depth [H,W], alpha [H,W], and for the backward: final T [H,W], last contributor
// [H,W] (1-based position in the tile list), tile offsets, tile lists (ranks), entry slots, rank ->
// Gaussian order, rank -> first slot, the splat records by rank.
ForwardResult rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                                const at::Tensor& opacities, const at::Tensor& depths, const at::Tensor& radii,
                                int64_t width, int64_t height, const at::Tensor& background) {
  check_inputs(means2d, conics, colors, opacities, depths, radii, width, height, background);
  const int W = static_cast<int>(width), H = static_cast<int>(height);
  const int tiles_x = (W + kTile - 1) / kTile, tiles_y = (H + kTile - 1) / kTile;
  gsgs_phase::Lap lap;
  Binning b = bin_gaussians(means2d, conics, colors, opacities, depths, radii, tiles_x, tiles_y);
  lap(gsgs_phase::kBinning);

  at::Tensor color = at::empty({H, W, 3}, at::kFloat);
  at::Tensor depth = at::empty({H, W}, at::kFloat);
  at::Tensor alpha = at::empty({H, W}, at::kFloat);
  at::Tensor final_T = at::empty({H, W}, at::kFloat);
  at::Tensor last = at::empty({H, W}, at::kInt);
  const int32_t* offsets = b.tile_offsets.data_ptr<int32_t>();
  const int32_t* ranks = b.tile_ranks.data_ptr<int32_t>();
  const float* bg = background.data_ptr<float>();
  float* color_p = color.data_ptr<float>();
  float* depth_p = depth.data_ptr<float>();
  float* alpha_p = alpha.data_ptr<float>();
  float* T_p = final_T.data_ptr<float>();
  int32_t* last_p = last.data_ptr<int32_t>();
  const Splat* const splats = splat_records(b.splats);
  const ForwardTileFn forward_tile = tile_kernels().forward;
  for_each_tile(tile_schedule(offsets, tiles_x * tiles_y), [&](int32_t t) {
    const int tx = t % tiles_x, ty = t / tiles_x;
    forward_tile(splats, ranks + offsets[t], offsets[t + 1] - offsets[t], tx * kTile, ty * kTile, W, H,
                 bg, color_p, depth_p, alpha_p, T_p, last_p);
  });

  lap(gsgs_phase::kRasterForward);
  const int64_t n_vis = static_cast<int64_t>(b.order.size());
  at::Tensor order = at::empty({n_vis}, at::kInt);
  at::Tensor slot_offset = at::empty({n_vis + 1}, at::kInt);
  if (n_vis > 0) std::memcpy(order.data_ptr<int32_t>(), b.order.data(), n_vis * sizeof(int32_t));
  std::memcpy(slot_offset.data_ptr<int32_t>(), b.slot_offset.data(), (n_vis + 1) * sizeof(int32_t));
  return {color, depth, alpha, final_T, last, b.tile_offsets, b.tile_ranks, b.entry_slots, order, slot_offset,
          b.splats};
}

// -> grad means2d [N,2], conics [N,3], colors [N,3], opacities [N], depths [N].
std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor> rasterize_backward(
    const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors, const at::Tensor& opacities,
    const at::Tensor& depths, const at::Tensor& radii, int64_t width, int64_t height, const at::Tensor& background,
    const at::Tensor& final_T, const at::Tensor& last, const at::Tensor& tile_offsets, const at::Tensor& tile_ranks,
    const at::Tensor& entry_slots, const at::Tensor& order, const at::Tensor& slot_offset, const at::Tensor& splat_t,
    const at::Tensor& grad_color, const at::Tensor& grad_depth, const at::Tensor& grad_alpha, bool absgrad) {
  check_inputs(means2d, conics, colors, opacities, depths, radii, width, height, background);
  const int W = static_cast<int>(width), H = static_cast<int>(height);
  const int tiles_x = (W + kTile - 1) / kTile, tiles_y = (H + kTile - 1) / kTile;
  const int n_tiles = tiles_x * tiles_y;
  const int64_t n = means2d.size(0);
  const int64_t n_vis = order.size(0);
  for (const at::Tensor* t : {&final_T, &grad_depth, &grad_alpha}) {
    TORCH_CHECK(t->scalar_type() == at::kFloat && t->is_contiguous() && t->sizes() == at::IntArrayRef({H, W}),
                "rasterize_cpu backward: per-pixel tensors must be contiguous float32 [H, W]");
  }
  TORCH_CHECK(grad_color.scalar_type() == at::kFloat && grad_color.is_contiguous() &&
                  grad_color.sizes() == at::IntArrayRef({H, W, 3}),
              "rasterize_cpu backward: grad_color must be contiguous float32 [H, W, 3]");
  TORCH_CHECK(last.scalar_type() == at::kInt && last.is_contiguous() && last.numel() == int64_t(H) * W,
              "rasterize_cpu backward: bad saved state");
  TORCH_CHECK(tile_offsets.numel() == n_tiles + 1 && slot_offset.numel() == n_vis + 1,
              "rasterize_cpu backward: saved state does not match the image size");

  TORCH_CHECK(splat_t.scalar_type() == at::kFloat && splat_t.is_contiguous() &&
                  splat_t.sizes() == at::IntArrayRef({n_vis, kSplatFloats}),
              "rasterize_cpu backward: bad saved state (splat records)");

  gsgs_phase::Lap lap;
  const int32_t* ord = order.data_ptr<int32_t>();
  const Splat* const splats = splat_records(splat_t);  // the forward's records: the same skip decisions

  const int32_t* offsets = tile_offsets.data_ptr<int32_t>();
  const int32_t* ranks = tile_ranks.data_ptr<int32_t>();
  const int32_t* slots = entry_slots.data_ptr<int32_t>();
  const int64_t n_entries = tile_ranks.numel();
  // Every record is written exactly once by its tile, so the buffer needs no zeroing (~40 bytes per entry).
  float* const records = reusable_buffer<float, 2>(static_cast<size_t>(n_entries) * kGradFields);
  // With absgrad, AbsGS's statistic: 2 floats per entry (|dL_p/dmx|, |dL_p/dmy| summed over the entry's pixels).
  float* const abs_records = absgrad ? reusable_buffer<float, 3>(static_cast<size_t>(n_entries) * 2) : nullptr;
  const float* bg = background.data_ptr<float>();
  const float* T_p = final_T.data_ptr<float>();
  const int32_t* last_p = last.data_ptr<int32_t>();
  const float* gc = grad_color.data_ptr<float>();
  const float* gd = grad_depth.data_ptr<float>();
  const float* ga = grad_alpha.data_ptr<float>();
  // Training losses rarely use depth: without a depth gradient its terms are skipped in the tile loop.
  const bool with_depth = std::any_of(gd, gd + static_cast<int64_t>(H) * W, [](float g) { return g != 0.0f; });
  lap(gsgs_phase::kBackwardPrep);
  const BackwardTileFn backward_tile = tile_kernels().backward;
  for_each_tile(tile_schedule(offsets, n_tiles), [&](int32_t t) {
    const int tx = t % tiles_x, ty = t / tiles_x;
    backward_tile(splats, ranks + offsets[t], slots + offsets[t], offsets[t + 1] - offsets[t], tx * kTile,
                  ty * kTile, W, H, bg, T_p, last_p, gc, gd, ga, with_depth, records, abs_records);
  });

  lap(gsgs_phase::kRasterBackward);
  at::Tensor g_means = at::zeros({n, 2}, at::kFloat);
  at::Tensor g_conics = at::zeros({n, 3}, at::kFloat);
  at::Tensor g_colors = at::zeros({n, 3}, at::kFloat);
  at::Tensor g_opac = at::zeros({n}, at::kFloat);
  at::Tensor g_depth = at::zeros({n}, at::kFloat);
  at::Tensor g_abs = at::zeros({absgrad ? n : 0, 2}, at::kFloat);
  float* gm = g_means.data_ptr<float>();
  float* gabs = g_abs.data_ptr<float>();
  float* gk = g_conics.data_ptr<float>();
  float* gcol = g_colors.data_ptr<float>();
  float* go = g_opac.data_ptr<float>();
  float* gz = g_depth.data_ptr<float>();
  const int32_t* soff = slot_offset.data_ptr<int32_t>();
  // Each Gaussian's records are contiguous and summed in tile order: deterministic.
  at::parallel_for(0, n_vis, 1024, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      float sum[kGradFields] = {0};
      for (int32_t e = soff[s]; e < soff[s + 1]; ++e) {
        const float* rec = records + static_cast<int64_t>(e) * kGradFields;
        for (int f = 0; f < kGradFields; ++f) sum[f] += rec[f];
      }
      const int64_t g = ord[s];
      gm[2 * g] = sum[0];
      gm[2 * g + 1] = sum[1];
      gk[3 * g] = sum[2];
      gk[3 * g + 1] = sum[3];
      gk[3 * g + 2] = sum[4];
      gcol[3 * g] = sum[5];
      gcol[3 * g + 1] = sum[6];
      gcol[3 * g + 2] = sum[7];
      go[g] = sum[8];
      gz[g] = sum[9];
      if (abs_records != nullptr) {
        float ax = 0.0f, ay = 0.0f;
        for (int32_t e = soff[s]; e < soff[s + 1]; ++e) {
          ax += abs_records[2 * static_cast<int64_t>(e)];
          ay += abs_records[2 * static_cast<int64_t>(e) + 1];
        }
        gabs[2 * g] = ax;
        gabs[2 * g + 1] = ay;
      }
    }
  });
  lap(gsgs_phase::kBackwardReduce);
  return {g_means, g_conics, g_colors, g_opac, g_depth, g_abs};
}

}  // namespace

at::Tensor phase_seconds() {
  at::Tensor out = at::empty({gsgs_phase::kCount}, at::kDouble);
  for (int i = 0; i < gsgs_phase::kCount; ++i) out.data_ptr<double>()[i] = gsgs_phase::g_ns[i].load() * 1e-9;
  return out;
}

void reset_phase_seconds() {
  for (auto& c : gsgs_phase::g_ns) c.store(0);
}

TORCH_LIBRARY(gsgs_raster_cpu, m) {
  m.def("phase_seconds() -> Tensor", &phase_seconds);
  m.def("reset_phase_seconds() -> ()", &reset_phase_seconds);
  m.def(
      "forward(Tensor means2d, Tensor conics, Tensor colors, Tensor opacities, Tensor depths, Tensor radii, "
      "int width, int height, Tensor background) -> (Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, "
      "Tensor, Tensor, Tensor, Tensor)",
      &rasterize_forward);
  m.def(
      "backward(Tensor means2d, Tensor conics, Tensor colors, Tensor opacities, Tensor depths, Tensor radii, "
      "int width, int height, Tensor background, Tensor final_T, Tensor last, Tensor tile_offsets, "
      "Tensor tile_ranks, Tensor entry_slots, Tensor order, Tensor slot_offset, Tensor splats, Tensor grad_color, "
      "Tensor grad_depth, Tensor grad_alpha, bool absgrad=False) -> (Tensor, Tensor, Tensor, Tensor, Tensor, Tensor)",
      &rasterize_backward);
}
