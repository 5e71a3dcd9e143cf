#pragma once
// The pieces the AVX2 Winograd forward pass (nn/winograd_avx2.cpp) and its weight gradient
// (nn/winograd_avx2_weight_grad.cpp) share: the AVX2 ports of the AVX-512 kernels of
// nn/winograd_tiles.h. Same tile geometry and by-phase layout (nn/winograd_geom.h), same packed
// transformed weights; each 16-tile group of the layout is two 8-lane vectors. Baseline code
// (x86-64-v3): no instruction-set region. Internal to nn/.
#include <cstddef>

#include "nn/big_alloc.h"
#include "nn/cpu_features.h"
#include "nn/winograd.h"
#include "nn/winograd_geom.h"

#if LIDARSIM_AVX2_KERNELS
#include <immintrin.h>

namespace lidarsim::nn::detail::avx2::wino {

constexpr int kCB = 8;  // output channels per block of the packed transformed weights

using Buf = GrowBuffer;  // nn/big_alloc.h
using winograd_layout::Geom;
using winograd_layout::plane_of;

// Per-thread transform scratch, shared by the forward pass and the weight gradient (they never
// run at the same time on one thread).
extern thread_local Buf tl_v, tl_m;

// B^T applied to 6 values: the input transform's 1-D step.
inline void bt6(const __m256 x[6], __m256 r[6]) {
  const __m256 four = _mm256_set1_ps(4.f), five = _mm256_set1_ps(5.f), two = _mm256_set1_ps(2.f);
  r[0] = _mm256_fnmadd_ps(five, x[2], _mm256_fmadd_ps(four, x[0], x[4]));
  const __m256 s12 = _mm256_add_ps(x[1], x[2]), d12 = _mm256_sub_ps(x[1], x[2]);
  r[1] = _mm256_fnmadd_ps(four, s12, _mm256_add_ps(x[4], x[3]));
  r[2] = _mm256_fmadd_ps(four, d12, _mm256_sub_ps(x[4], x[3]));
  const __m256 d42 = _mm256_sub_ps(x[4], x[2]), d31 = _mm256_sub_ps(x[3], x[1]);
  r[3] = _mm256_fmadd_ps(two, d31, d42);
  r[4] = _mm256_fnmadd_ps(two, d31, d42);
  r[5] = _mm256_fnmadd_ps(five, x[3], _mm256_fmadd_ps(four, x[1], x[5]));
}

// The input transform's second step: B^T down the columns of the row-transformed tile t, each
// of the 36 elements stored (aligned) e_stride floats apart.
inline void bt_columns_store(float* v, std::size_t e_stride, const __m256 t[6][6]) {
  for (int bb = 0; bb < 6; ++bb) {
    __m256 col[6], r[6];
    for (int i = 0; i < 6; ++i) col[i] = t[i][bb];
    bt6(col, r);
    for (int a = 0; a < 6; ++a) _mm256_store_ps(v + (a * 6 + bb) * e_stride, r[a]);
  }
}

// Lanes [0, n) set (n clamped to 0..8): the mask of _mm256_maskstore_ps / _mm256_maskload_ps.
inline __m256i first_lanes(int n) {
  return _mm256_cmpgt_epi32(_mm256_set1_epi32(n), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
}

// Fills the by-phase layout of every (image, channel) plane, masked when mask is given; with
// sums, sums[plane] gets each plane's (masked) sum as well, in an order fixed by the plane's
// width (so the same bits on any thread count).
void to_phases(float* dst, const PlaneSet& in, const float* mask, int n, const Geom& g, float* sums = nullptr);

// The conv of winograd_conv3x3 from the by-phase copy of its input (ci channels).
void conv_from_phases(const OutPlaneSet& out, const float* phases, int ci, int n, const Geom& g, const float* weight,
                      bool transpose_flip, const float* bias, bool relu);

}  // namespace lidarsim::nn::detail::avx2::wino

#endif
