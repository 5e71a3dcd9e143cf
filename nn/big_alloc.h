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

// Grow-only, 64-byte aligned float scratch (the convolution kernels' per-op buffers): reused
// across steps, so steady-state steps allocate nothing.
struct GrowBuffer {
  float* p = nullptr;
  std::size_t n = 0;
  float* get(std::size_t want) {
    if (want > n) {
      std::free(p);
      p = nullptr;  // a throw below leaves an empty buffer
      n = 0;
      p = static_cast<float*>(aligned_storage(want * sizeof(float)));
      n = want;
    }
    return p;
  }
  GrowBuffer() = default;
  GrowBuffer(const GrowBuffer&) = delete;
  GrowBuffer& operator=(const GrowBuffer&) = delete;
  ~GrowBuffer() { std::free(p); }
};

}  // namespace lidarsim::nn::detail
