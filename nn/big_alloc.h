#pragma once
// 64-byte aligned storage for tensors and kernel scratch, released with std::free. Buffers of
// 4 MB and more are 2 MB aligned and asked to be backed by transparent huge pages (the host's
// THP mode is "madvise": without asking, every buffer is 4 KB pages). The kernels walk many
// channel planes of 64 x 1024 maps at once, and with 4 KB pages the TLB misses showed: the
// unet-ref training step at batch 4 took 1.5-2 % longer (same-run A/B).
#include <cstddef>
#include <cstdlib>

namespace lidarsim::nn::detail {

// Throws std::bad_alloc when out of memory.
void* aligned_storage(std::size_t bytes);

// Grow-only, 64-byte aligned scratch of T (the kernels' per-op buffers: floats, bf16 pairs, bytes):
// reused across steps, so steady-state steps allocate nothing.
template <typename T>
struct GrowArray {
  T* p = nullptr;
  std::size_t n = 0;
  T* get(std::size_t want) {
    if (want > n) {
      std::free(p);
      p = nullptr;  // a throw below leaves an empty buffer
      n = 0;
      p = static_cast<T*>(aligned_storage(want * sizeof(T)));
      n = want;
    }
    return p;
  }
  GrowArray() = default;
  GrowArray(const GrowArray&) = delete;
  GrowArray& operator=(const GrowArray&) = delete;
  ~GrowArray() { std::free(p); }
};
using GrowBuffer = GrowArray<float>;

}  // namespace lidarsim::nn::detail
