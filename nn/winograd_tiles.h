#pragma once
// The pieces the Winograd forward pass (nn/winograd.cpp) and its weight gradient
// (nn/winograd_weight_grad.cpp) share: the tile geometry, the by-phase layout of the planes
// (nn/winograd_phases.cpp), the input transform and the scratch buffers. Internal to nn/.
#include <algorithm>
#include <cstddef>
#include <cstdlib>

#include "nn/big_alloc.h"
#include "nn/cpu_features.h"
#include "nn/winograd.h"
#include "nn/winograd_geom.h"

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512::wino {

constexpr int kCB = 8;  // output channels per GEMM register block

using Buf = GrowBuffer;  // nn/big_alloc.h

// Per-thread transform scratch, shared by the forward pass and the weight gradient (they never
// run at the same time on one thread).
extern thread_local Buf tl_v, tl_m;

// The tile geometry and the by-phase layout (nn/winograd_geom.h).
using winograd_layout::Geom;
using winograd_layout::plane_of;

// Bits [lo, hi) of a 16-lane mask, clamped to 0..16.
inline __mmask16 lane_range(int lo, int hi) {
  lo = std::max(lo, 0);
  hi = std::min(hi, 16);
  if (hi <= lo) return 0;
  return static_cast<__mmask16>(((1u << hi) - 1) & ~((1u << lo) - 1));
}

// B^T applied to 6 values: the input transform's 1-D step.
inline void bt6(const __m512 x[6], __m512 r[6]) {
  const __m512 four = _mm512_set1_ps(4.f), five = _mm512_set1_ps(5.f), two = _mm512_set1_ps(2.f);
  r[0] = _mm512_fnmadd_ps(five, x[2], _mm512_fmadd_ps(four, x[0], x[4]));
  const __m512 s12 = _mm512_add_ps(x[1], x[2]), d12 = _mm512_sub_ps(x[1], x[2]);
  r[1] = _mm512_fnmadd_ps(four, s12, _mm512_add_ps(x[4], x[3]));
  r[2] = _mm512_fmadd_ps(four, d12, _mm512_sub_ps(x[4], x[3]));
  const __m512 d42 = _mm512_sub_ps(x[4], x[2]), d31 = _mm512_sub_ps(x[3], x[1]);
  r[3] = _mm512_fmadd_ps(two, d31, d42);
  r[4] = _mm512_fnmadd_ps(two, d31, d42);
  r[5] = _mm512_fnmadd_ps(five, x[3], _mm512_fmadd_ps(four, x[1], x[5]));
}

// The input transform's second step: B^T down the columns of the row-transformed tile t, each
// of the 36 elements stored e_stride floats apart.
inline void bt_columns_store(float* v, std::size_t e_stride, const __m512 t[6][6]) {
  for (int bb = 0; bb < 6; ++bb) {
    __m512 col[6], r[6];
    for (int i = 0; i < 6; ++i) col[i] = t[i][bb];
    bt6(col, r);
    for (int a = 0; a < 6; ++a) _mm512_store_ps(v + (a * 6 + bb) * e_stride, r[a]);
  }
}

// Fills the by-phase layout of every (image, channel) plane, masked when mask is given; with
// sums, sums[plane] gets each plane's sum as well (in the bias gradient's plain order).
void to_phases(float* dst, const PlaneSet& in, const float* mask, int n, const Geom& g, float* sums = nullptr);

// The conv of winograd_conv3x3 from the by-phase copy of its input (ci channels).
void conv_from_phases(const OutPlaneSet& out, const float* phases, int ci, int n, const Geom& g, const float* weight,
                      bool transpose_flip, const float* bias, bool relu);

}  // namespace lidarsim::nn::detail::avx512::wino
#include "nn/isa_avx512_end.h"

#endif
