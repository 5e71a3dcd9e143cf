// libFuzzer entry: one executable per target, chosen at compile time (LIDARSIM_FUZZ_TARGET).
#include <cstddef>
#include <cstdint>

#include "fuzz/readers.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const lidarsim::fuzz::Entry entry = lidarsim::fuzz::find_target(LIDARSIM_FUZZ_TARGET);
  entry(data, size);
  return 0;
}
