// Wall time spent in each phase of the compiled renderer, accumulated across calls (for profiles:
// `gsgs_raster_cpu::phase_seconds` reads them, `reset_phase_seconds` zeroes them). Two clock reads
// per phase per call: negligible next to the work they time.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>

namespace gsgs_phase {

enum Phase : int {
  kProjectForward = 0,
  kBinning,          // depth sort, tile lists, packed records
  kRasterForward,    // per-tile compositing
  kBackwardPrep,     // records rebuilt, gradient buffers
  kRasterBackward,   // per-tile backward
  kBackwardReduce,   // per-Gaussian sums of the per-entry records
  kProjectBackward,
  kCount
};

inline std::atomic<int64_t> g_ns[kCount];

inline int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// Adds the time since construction (or the previous lap) to a phase.
struct Lap {
  int64_t t = now_ns();
  void operator()(Phase p) {
    const int64_t n = now_ns();
    g_ns[p].fetch_add(n - t, std::memory_order_relaxed);
    t = n;
  }
};

}  // namespace gsgs_phase
