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
};

}  // namespace gsgs_lanes
