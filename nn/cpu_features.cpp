#include "nn/cpu_features.h"

#include <cstdlib>

#include "common/error.h"

namespace lidarsim::nn {

const char* const kIsaNames[kIsaCount] = {"avx2", "avx512", "avx512_bf16"};

namespace {

Isa detect() {
#if LIDARSIM_AVX512_KERNELS
  __builtin_cpu_init();
  const bool avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                      __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq");
  if (!avx512) return Isa::avx2;
  return __builtin_cpu_supports("avx512bf16") ? Isa::avx512_bf16 : Isa::avx512;
#else
  return Isa::avx2;
#endif
}

// `level` if the CPU has it, else an Error naming `field`.
Isa require(Isa level, const std::string& field) {
  if (static_cast<int>(level) > static_cast<int>(cpu_isa()))
    throw Error(field + ": " + to_string(level) + " requested, but this CPU runs at most " + to_string(cpu_isa()));
  return level;
}

Isa read_isa_env() {
  const char* env = std::getenv("LIDARSIM_ISA");
  const std::string v = env ? env : "";
  if (v.empty() || v == "auto") return cpu_isa();
  return require(parse_isa(v, "environment: LIDARSIM_ISA"), "environment: LIDARSIM_ISA");
}

Isa& active() {
  static Isa level = read_isa_env();
  return level;
}

}  // namespace

const char* to_string(Isa isa) { return kIsaNames[static_cast<int>(isa)]; }

Isa parse_isa(const std::string& text, const std::string& field) {
  for (int i = 0; i < kIsaCount; ++i)
    if (text == kIsaNames[i]) return static_cast<Isa>(i);
  throw Error(field + ": expected auto, avx2, avx512 or avx512_bf16, got \"" + text + "\"");
}

Isa cpu_isa() {
  static const Isa level = detect();
  return level;
}

Isa active_isa() { return active(); }

namespace testhook {
void set_isa(Isa level) { active() = require(level, "testhook::set_isa"); }
ScopedIsa::ScopedIsa(Isa level) : old(active_isa()) { set_isa(level); }
ScopedIsa::~ScopedIsa() { active() = old; }
}  // namespace testhook

}  // namespace lidarsim::nn
