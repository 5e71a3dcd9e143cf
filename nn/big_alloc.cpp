#include "nn/big_alloc.h"

#include <cstdlib>
#include <new>

#ifdef __linux__
#include <sys/mman.h>
#endif

namespace lidarsim::nn::detail {

void* aligned_storage(std::size_t bytes) {
  constexpr std::size_t kHuge = std::size_t{2} << 20;
  void* p = nullptr;
  if (bytes >= 2 * kHuge) {
    const std::size_t size = (bytes + kHuge - 1) / kHuge * kHuge;
    p = std::aligned_alloc(kHuge, size);
#ifdef __linux__
    if (p) madvise(p, size, MADV_HUGEPAGE);  // a hint: without THP it changes nothing
#endif
  } else {
    p = std::aligned_alloc(64, bytes < 64 ? 64 : (bytes + 63) / 64 * 64);
  }
  if (!p) throw std::bad_alloc();
  return p;
}

}  // namespace lidarsim::nn::detail
