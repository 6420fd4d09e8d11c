// Lane policies of the compiled projection (project_cpu.cpp): its arithmetic is written once, over L::T, which
// is one Gaussian's scalar (One<S>: float or double) or eight Gaussians' float lanes (Eight: GCC vector
// extensions, AVX in the AVX2 clone, two SSE registers in the portable one). Every operation of the eight-lane
// form is the IEEE operation of the one-lane form on each lane, in the same order (the build has no FMA
// contraction: -ffp-contract=off), so eight lanes give the one-lane results bit for bit; the branches of the
// one-lane code are selects here, and where a lane's branch is not taken its value is selected away.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace gsgs_lanes {

#define GSGS_LANE_INLINE inline __attribute__((always_inline))
#pragma GCC diagnostic ignored "-Wpsabi"

template <typename S_>
struct One {
  using S = S_;
  using T = S_;
  using M = bool;
  static constexpr int kWidth = 1;
  static GSGS_LANE_INLINE T splat(S v) { return v; }
  static GSGS_LANE_INLINE T sel(M m, T a, T b) { return m ? a : b; }
  static GSGS_LANE_INLINE M both(M a, M b) { return a && b; }
  static GSGS_LANE_INLINE M either(M a, M b) { return a || b; }
  static GSGS_LANE_INLINE M none() { return false; }
  static GSGS_LANE_INLINE T max(T a, T b) { return std::max(a, b); }
  static GSGS_LANE_INLINE T min(T a, T b) { return std::min(a, b); }
  static GSGS_LANE_INLINE M finite(T x) { return std::isfinite(x); }
  static GSGS_LANE_INLINE T sqrt(T x) { return std::sqrt(x); }
  // Field c of records of `stride` values, Gaussian g (and, for Eight, the seven after it).
  static GSGS_LANE_INLINE T load(const S* p, int64_t stride, int64_t g, int64_t c) { return p[stride * g + c]; }
  static GSGS_LANE_INLINE void store(S* p, int64_t stride, int64_t g, int64_t c, T v) { p[stride * g + c] = v; }
  static GSGS_LANE_INLINE S lane(T v, int) { return v; }
  static GSGS_LANE_INLINE bool lane(M m, int) { return m; }
  // Fields [0, count) of Gaussian g's record (count <= stride) -> out[0, count).
  static GSGS_LANE_INLINE void load_fields(const S* p, int64_t stride, int64_t g, int count, T* out) {
    for (int c = 0; c < count; ++c) out[c] = p[stride * g + c];
  }
  // v(c) for every field c of Gaussian g's record.
  template <typename F>
  static GSGS_LANE_INLINE void store_fields(S* p, int64_t stride, int64_t g, F&& v) {
    for (int64_t c = 0; c < stride; ++c) p[stride * g + c] = v(c);
  }
};

typedef float f8 __attribute__((vector_size(32)));
typedef int32_t i8 __attribute__((vector_size(32)));

struct Eight {
  using S = float;
  using T = f8;
  using M = i8;  // all bits set on a lane where true
  static constexpr int kWidth = 8;
  static GSGS_LANE_INLINE T splat(S v) { return T{} + v; }
  static GSGS_LANE_INLINE T sel(M m, T a, T b) { return (T)(((M)a & m) | ((M)b & ~m)); }
  static GSGS_LANE_INLINE M both(M a, M b) { return a & b; }
  static GSGS_LANE_INLINE M either(M a, M b) { return a | b; }
  static GSGS_LANE_INLINE M none() { return M{}; }
  // std::max(a, b) is (a < b) ? b : a and std::min(a, b) is (b < a) ? b : a: the same lane for NaN too.
  static GSGS_LANE_INLINE T max(T a, T b) { return sel(a < b, b, a); }
  static GSGS_LANE_INLINE T min(T a, T b) { return sel(b < a, b, a); }
  static GSGS_LANE_INLINE M finite(T x) { return (x - x) == splat(0.0f); }  // inf - inf and NaN - NaN are NaN
  static GSGS_LANE_INLINE T sqrt(T x) {
    T r;
    for (int i = 0; i < kWidth; ++i) r[i] = std::sqrt(x[i]);
    return r;
  }
  static GSGS_LANE_INLINE T load(const S* p, int64_t stride, int64_t g, int64_t c) {
    T v;
    for (int i = 0; i < kWidth; ++i) v[i] = p[stride * (g + i) + c];
    return v;
  }
  static GSGS_LANE_INLINE void store(S* p, int64_t stride, int64_t g, int64_t c, T v) {
    for (int i = 0; i < kWidth; ++i) p[stride * (g + i) + c] = v[i];
  }
  static GSGS_LANE_INLINE S lane(T v, int i) { return v[i]; }
  static GSGS_LANE_INLINE bool lane(M m, int i) { return m[i] != 0; }
  // Fields [0, count) of the records of Gaussians g .. g + 7 (count <= stride) -> out[0, count), out holding
  // count rounded up to 8: whole runs of 8 fields are loaded as rows and transposed, the rest one by one.
  static GSGS_LANE_INLINE void load_fields(const S* p, int64_t stride, int64_t g, int count, T* out) {
    int c = 0;
    for (; c < count && c + kWidth <= stride; c += kWidth) {
      T rows[kWidth];
      for (int i = 0; i < kWidth; ++i) std::memcpy(&rows[i], p + stride * (g + i) + c, sizeof(T));
      transpose(rows, out + c);
    }
    for (; c < count; ++c) out[c] = load(p, stride, g, c);
  }
  // v(c) for every field c of the records of Gaussians g .. g + 7: transposed into rows of 8 fields where whole.
  template <typename F>
  static GSGS_LANE_INLINE void store_fields(S* p, int64_t stride, int64_t g, F&& v) {
    int64_t c = 0;
    for (; c + kWidth <= stride; c += kWidth) {
      T cols[kWidth], rows[kWidth];
      for (int j = 0; j < kWidth; ++j) cols[j] = v(c + j);
      transpose(cols, rows);
      for (int i = 0; i < kWidth; ++i) std::memcpy(p + stride * (g + i) + c, &rows[i], sizeof(T));
    }
    for (; c < stride; ++c) store(p, stride, g, c, v(c));
  }
  // out[j][i] = in[i][j] (8 x 8): pairs, then quads, then halves exchanged.
  static GSGS_LANE_INLINE void transpose(const T* in, T* out) {
    T a[8], b[8];
    for (int k = 0; k < 4; ++k) {
      a[2 * k] = __builtin_shuffle(in[2 * k], in[2 * k + 1], i8{0, 8, 2, 10, 4, 12, 6, 14});
      a[2 * k + 1] = __builtin_shuffle(in[2 * k], in[2 * k + 1], i8{1, 9, 3, 11, 5, 13, 7, 15});
    }
    for (int h = 0; h < 2; ++h) {  // rows 4h .. 4h + 3
      T* bb = b + 4 * h;
      const T* aa = a + 4 * h;
      bb[0] = __builtin_shuffle(aa[0], aa[2], i8{0, 1, 8, 9, 4, 5, 12, 13});  // columns 0 and 4
      bb[2] = __builtin_shuffle(aa[0], aa[2], i8{2, 3, 10, 11, 6, 7, 14, 15});  // columns 2 and 6
      bb[1] = __builtin_shuffle(aa[1], aa[3], i8{0, 1, 8, 9, 4, 5, 12, 13});  // columns 1 and 5
      bb[3] = __builtin_shuffle(aa[1], aa[3], i8{2, 3, 10, 11, 6, 7, 14, 15});  // columns 3 and 7
    }
    for (int j = 0; j < 4; ++j) {
      out[j] = __builtin_shuffle(b[j], b[4 + j], i8{0, 1, 2, 3, 8, 9, 10, 11});
      out[j + 4] = __builtin_shuffle(b[j], b[4 + j], i8{4, 5, 6, 7, 12, 13, 14, 15});
    }
  }
};

}  // namespace gsgs_lanes
