// Scratch memory kept per calling thread between calls of the compiled ops.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

namespace gsgs_scratch {

// n values of T kept per calling thread between calls (Tag tells apart buffers alive at the same time):
// a training step would otherwise take fresh pages, and have them cleared, for every one of them each
// time. The contents are unspecified; callers write every value they read. Take the pointer in the
// calling thread: a thread_local named inside a parallel lambda is each worker's own.
template <typename T, int Tag>
T* reusable_buffer(size_t n) {
  static thread_local std::vector<T> buffer;
  if (buffer.size() < n || buffer.size() > 4 * n + (size_t{1} << 16)) {
    std::vector<T>().swap(buffer);
    buffer.resize(std::max<size_t>(n, 1));
  }
  return buffer.data();
}

}  // namespace gsgs_scratch
