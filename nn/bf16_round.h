#pragma once
// The one rounding of fp32 weights to bf16 shared by the bf16 kernels (nn/conv3x3_bf16.cpp,
// nn/conv3x3_amx.cpp), so both see the same weight bits; activations go through the hardware
// conversion (vcvtne(2)ps2bf16), which rounds the same way.
#include <cstdint>
#include <cstring>

namespace lidarsim::nn::detail {

// Round to nearest even, as the hardware conversion does for the activations.
inline std::uint32_t bf16_bits(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  if ((u & 0x7fffffffu) > 0x7f800000u) return (u >> 16) | 0x40u;  // NaN stays NaN
  return (u + 0x7fffu + ((u >> 16) & 1u)) >> 16;
}

}  // namespace lidarsim::nn::detail
