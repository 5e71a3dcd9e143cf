#include "nn/cpu_features.h"

#include <cstdlib>

#include "common/error.h"

#if LIDARSIM_AVX512_KERNELS
#include <cpuid.h>
#endif
#if LIDARSIM_AVX512_KERNELS && defined(__linux__)
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace lidarsim::nn {

const char* const kIsaNames[kIsaCount] = {"avx2", "avx512", "avx512_bf16", "amx_bf16"};

namespace {

#if LIDARSIM_AVX512_KERNELS
// AMX needs three things: the CPU's AMX-TILE and AMX-BF16 (CPUID leaf 7, EDX bits 24 and 22),
// the OS saving the tile state (XCR0 bits 17 and 18), and, on Linux, this process's permission
// to use the 8 KB tile data (arch_prctl ARCH_REQ_XCOMP_PERM): without it the first tile
// instruction is SIGILL. The permission is per process (every thread, later ones too), asked for
// once here, at detection.
bool amx_usable() {
#if defined(__linux__)
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (!__get_cpuid_count(7, 0, &a, &b, &c, &d)) return false;
  if (!(d & (1u << 22)) || !(d & (1u << 24))) return false;
  unsigned c1 = 0;
  if (!__get_cpuid(1, &a, &b, &c1, &d) || !(c1 & (1u << 27))) return false;  // OSXSAVE: xgetbv exists
  unsigned lo = 0, hi = 0;
  __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));  // (no -mxsave needed for the asm)
  if ((lo & (3u << 17)) != (3u << 17)) return false;
  constexpr long kReqXcompPerm = 0x1023, kXfeatureXtiledata = 18;
  return syscall(SYS_arch_prctl, kReqXcompPerm, kXfeatureXtiledata) == 0;
#else
  return false;
#endif
}
#endif

Isa detect() {
#if LIDARSIM_AVX512_KERNELS
  __builtin_cpu_init();
  const bool avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                      __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq");
  if (!avx512) return Isa::avx2;
  if (!__builtin_cpu_supports("avx512bf16")) return Isa::avx512;
  return amx_usable() ? Isa::amx_bf16 : Isa::avx512_bf16;
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
  throw Error(field + ": expected auto, avx2, avx512, avx512_bf16 or amx_bf16, got \"" + text + "\"");
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
