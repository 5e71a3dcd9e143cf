// Opens a region whose functions are compiled for AVX-512 (F, BW, VL, DQ) on top of the build's
// baseline; nn/isa_avx512_end.h closes it. No include guard: it is a switch, included once per
// region. Rules that keep AVX-512 instructions out of every other function (tests/isa checks the
// binaries):
// - include every header (standard library, Eigen, our own) BEFORE the region, so their inline
//   functions and templates stay baseline code; a copy compiled here could otherwise be the one
//   the linker keeps for all callers;
// - put the region's code in a namespace named avx512 (lidarsim::nn::detail::avx512, ...): the
//   ISA scan allows AVX-512 only in functions with avx512 in their name;
// - call into it only behind the run-time check (nn/cpu_features.h), and keep namespace-scope
//   objects with dynamic initialisers out of it (their initialiser runs at start-up).
// Baseline code can call these functions but never inline them (GCC and clang refuse to inline a
// callee with a wider target), and lambdas defined in the region are compiled for it too.
#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx512f,avx512bw,avx512vl,avx512dq"))), apply_to = function)
#elif defined(__GNUC__)
#pragma GCC push_options
#pragma GCC target("avx512f,avx512bw,avx512vl,avx512dq")
#endif
