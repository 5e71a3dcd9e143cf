#include "nn/precision.h"

#include <atomic>
#include <cstdio>
#include <cstdlib>

#include "common/error.h"
#include "nn/conv3x3_bf16.h"

namespace lidarsim::nn {

namespace {
InferencePrecision read_precision_env() {
  const char* env = std::getenv("LIDARSIM_INFER_PRECISION");
  if (!env || !*env) return InferencePrecision::fp32;
  return parse_inference_precision(env, "environment: LIDARSIM_INFER_PRECISION");
}
// Read on first use (not at static initialisation), so a bad value is the command's one-line error.
InferencePrecision& requested() {
  static InferencePrecision p = read_precision_env();
  return p;
}
bool g_forced_unsupported = false;
std::atomic<bool> g_warned{false};
}  // namespace

InferencePrecision parse_inference_precision(const std::string& text, const std::string& field) {
  if (text == "fp32") return InferencePrecision::fp32;
  if (text == "bf16") return InferencePrecision::bf16;
  throw Error(field + ": expected fp32 or bf16, got \"" + text + "\"");
}

const char* to_string(InferencePrecision p) { return p == InferencePrecision::bf16 ? "bf16" : "fp32"; }

void set_inference_precision(InferencePrecision p) { requested() = p; }
InferencePrecision inference_precision() { return requested(); }

bool bf16_supported() { return !g_forced_unsupported && detail::conv3x3_bf16_available(); }

InferencePrecision effective_inference_precision() { return effective_inference_precision(requested()); }

InferencePrecision effective_inference_precision(InferencePrecision p) {
  if (p != InferencePrecision::bf16 || bf16_supported()) return p;
  if (!g_warned.exchange(true))
    std::fprintf(stderr, "lidarsim: bf16 inference requested but this CPU has no AVX-512 BF16: running fp32\n");
  return InferencePrecision::fp32;
}

namespace testhook {
void force_bf16_unsupported(bool force) {
  g_forced_unsupported = force;
  g_warned = false;
}
}  // namespace testhook

}  // namespace lidarsim::nn
