#pragma once
// Inference precision of the UNet: fp32 (default) or bf16, where the 3x3
// convolutions of UNet::predict take bf16 inputs and weights with fp32 accumulation
// (nn/conv3x3_bf16.h). Training (forward/backward) is always fp32. Each UNet runs predict() in its
// own precision (UNet::set_inference_precision); one that was not given any takes the process
// default below: LIDARSIM_INFER_PRECISION (fp32 or bf16) read on first use, or what a command set
// from its --precision flag (before any thread runs a model: a plain value, not synchronised).
// bf16 needs AVX-512 BF16 at run time: without it inference stays fp32 and one line on stderr
// says so (once per process).
#include <string>

namespace lidarsim::nn {

enum class InferencePrecision { fp32, bf16 };

// "fp32" or "bf16"; anything else throws Error naming `field`.
InferencePrecision parse_inference_precision(const std::string& text, const std::string& field);
const char* to_string(InferencePrecision p);

// The process default (LIDARSIM_INFER_PRECISION until set).
void set_inference_precision(InferencePrecision p);
InferencePrecision inference_precision();

// Whether this CPU (and this build) runs the bf16 kernels.
bool bf16_supported();

// The precision predict() runs in for a request: `requested`, or fp32 with the one-line message
// when bf16 is requested and unsupported. Without an argument: for the process default.
InferencePrecision effective_inference_precision(InferencePrecision requested);
InferencePrecision effective_inference_precision();

namespace testhook {
// Test-only: pretend the CPU lacks AVX-512 BF16 (the fallback), and re-arm the one-time message.
void force_bf16_unsupported(bool force);
}  // namespace testhook


}  // namespace lidarsim::nn
