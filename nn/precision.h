#pragma once
// Inference precision of the UNet: fp32 (default) or bf16, where the 3x3
// convolutions of UNet::predict take bf16 inputs and weights with fp32 accumulation
// (nn/conv3x3_bf16.h). Training (forward/backward) is always fp32. The first use reads
// LIDARSIM_INFER_PRECISION (fp32 or bf16); commands may set it from a --precision flag.
// bf16 needs AVX-512 BF16 at run time: without it inference stays fp32 and one line on stderr
// says so (once per process).
#include <string>

namespace lidarsim::nn {

enum class InferencePrecision { fp32, bf16 };

// "fp32" or "bf16"; anything else throws Error naming `field`.
InferencePrecision parse_inference_precision(const std::string& text, const std::string& field);
const char* to_string(InferencePrecision p);

// The requested precision (LIDARSIM_INFER_PRECISION until set).
void set_inference_precision(InferencePrecision p);
InferencePrecision inference_precision();

// Whether this CPU (and this build) runs the bf16 kernels.
bool bf16_supported();

// The precision predict() runs in: the requested one, or fp32 with the one-line message when
// bf16 is requested and unsupported.
InferencePrecision effective_inference_precision();

namespace testhook {
// Test-only: pretend the CPU lacks AVX-512 BF16 (the fallback), and re-arm the one-time message.
void force_bf16_unsupported(bool force);
}  // namespace testhook

namespace detail {
// Set while UNet::predict runs in bf16: the 3x3 convolutions then take the bf16 kernel.
bool bf16_convs_active();
// Set while UNet::predict runs (any precision, by the same scope): the convolutions may keep
// their derived weights (nn/weight_cache.h).
bool predict_active();
struct Bf16ConvScope {
  explicit Bf16ConvScope(bool on);
  ~Bf16ConvScope();
  Bf16ConvScope(const Bf16ConvScope&) = delete;
  Bf16ConvScope& operator=(const Bf16ConvScope&) = delete;
  bool old;
};
}  // namespace detail

}  // namespace lidarsim::nn
