#pragma once
// The one place that decides which instruction set the engine's kernels use. The build's baseline
// is x86-64-v3 (AVX2, FMA; CMakeLists.txt, LIDARSIM_ARCH); the AVX-512 kernels are compiled in
// regions of their own (nn/isa_avx512_begin.h) and run only when active_isa() allows them, so one
// binary runs on any x86-64-v3 CPU and takes the wider kernels where the CPU has them.
//
// active_isa() is what the CPU reports (__builtin_cpu_supports, which also checks that the OS
// saves the registers), capped by LIDARSIM_ISA when set: `avx2` forces the baseline kernels
// everywhere (the sanitized CI pass runs so), `avx512` / `avx512_bf16` / `amx_bf16` require that
// level (a CPU without it is an error, not a silent fallback), `auto` or empty is the CPU's own
// level. Read once, on first use, so a bad value is the command's one-line error.
#include <string>

// Whether this compiler and target can build the AVX-512 kernels at all (x86-64, GCC or clang).
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define LIDARSIM_AVX512_KERNELS 1
#else
#define LIDARSIM_AVX512_KERNELS 0
#endif
// Whether the build's baseline has AVX2 and FMA (x86-64-v3 and up): the AVX2 ports of the kernels
// (nn/winograd_avx2.h) are then baseline code, run on every CPU the binary runs on.
#if defined(__AVX2__) && defined(__FMA__)
#define LIDARSIM_AVX2_KERNELS 1
#else
#define LIDARSIM_AVX2_KERNELS 0
#endif

namespace lidarsim::nn {

// Ordered: each level includes the ones before it.
enum class Isa {
  avx2,         // the build's baseline (x86-64-v3)
  avx512,       // AVX-512 F, BW, VL, DQ: the fp32 direct, Winograd, transposed-conv, pooling kernels
  avx512_bf16,  // plus AVX-512 BF16: bf16 inference (nn/conv3x3_bf16.h)
  amx_bf16,     // plus AMX-TILE and AMX-BF16, enabled by the OS for this process: nn/conv3x3_amx.h
};
constexpr int kIsaCount = 4;
extern const char* const kIsaNames[kIsaCount];
static_assert(static_cast<int>(Isa::amx_bf16) + 1 == kIsaCount, "kIsaNames lists every Isa");

const char* to_string(Isa isa);
// "avx2", "avx512", "avx512_bf16" or "amx_bf16"; anything else throws Error naming `field`.
Isa parse_isa(const std::string& text, const std::string& field);

// The widest level this CPU (and this build) runs.
Isa cpu_isa();
// The level the kernels use now: cpu_isa(), capped by LIDARSIM_ISA.
Isa active_isa();
inline bool isa_at_least(Isa level) { return static_cast<int>(active_isa()) >= static_cast<int>(level); }

namespace testhook {
// Test-only: run the kernels at `level` from now on (as LIDARSIM_ISA would); throws Error when
// the CPU lacks it. ScopedIsa restores the previous level.
void set_isa(Isa level);
struct ScopedIsa {
  explicit ScopedIsa(Isa level);
  ~ScopedIsa();
  ScopedIsa(const ScopedIsa&) = delete;
  ScopedIsa& operator=(const ScopedIsa&) = delete;
  Isa old;
};
}  // namespace testhook

}  // namespace lidarsim::nn
