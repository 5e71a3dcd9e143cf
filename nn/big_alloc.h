#pragma once
// 64-byte aligned storage for tensors and kernel scratch, released with std::free. Buffers of
// 4 MB and more are 2 MB aligned and asked to be backed by transparent huge pages (the host's
// THP mode is "madvise": without asking, every buffer is 4 KB pages). The kernels walk many
// channel planes of 64 x 1024 maps at once, and with 4 KB pages the TLB misses showed: the
// unet-ref training step at batch 4 took 1.5-2 % longer (same-run A/B).
#include <cstddef>

namespace lidarsim::nn::detail {

// Throws std::bad_alloc when out of memory.
void* aligned_storage(std::size_t bytes);

}  // namespace lidarsim::nn::detail
