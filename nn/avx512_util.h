#pragma once
// Small AVX-512 helpers shared by the hand-written kernels (conv3x3.cpp, winograd.cpp), compiled
// for AVX-512 in every file that includes them (nn/isa_avx512_begin.h).
#include "nn/cpu_features.h"
#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512 {

// Horizontal sum (GCC 12's _mm512_reduce_add_ps trips -Wuninitialized in its own header).
inline float hsum(__m512 v) {
  const __m512 t = _mm512_add_ps(v, _mm512_shuffle_f32x4(v, v, 0x4E));
  const __m256 a = _mm512_castps512_ps256(t);
  __m128 b = _mm_add_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1));
  b = _mm_add_ps(b, _mm_movehl_ps(b, b));
  b = _mm_add_ss(b, _mm_movehdup_ps(b));
  return _mm_cvtss_f32(b);
}

// col[x] lane k = r[k] lane x: the 16 x 16 transpose.
inline void transpose16(const __m512 r[16], __m512 col[16]) {
  __m512 t[16], u[16];
  for (int i = 0; i < 8; ++i) {
    t[2 * i] = _mm512_unpacklo_ps(r[2 * i], r[2 * i + 1]);
    t[2 * i + 1] = _mm512_unpackhi_ps(r[2 * i], r[2 * i + 1]);
  }
  // u[4 q + j], 128-bit chunk L: rows 4 q .. 4 q + 3 of column 4 L + j.
  for (int q = 0; q < 4; ++q) {
    const __m512d a = _mm512_castps_pd(t[4 * q]), b = _mm512_castps_pd(t[4 * q + 2]);
    const __m512d c = _mm512_castps_pd(t[4 * q + 1]), d = _mm512_castps_pd(t[4 * q + 3]);
    u[4 * q] = _mm512_castpd_ps(_mm512_unpacklo_pd(a, b));
    u[4 * q + 1] = _mm512_castpd_ps(_mm512_unpackhi_pd(a, b));
    u[4 * q + 2] = _mm512_castpd_ps(_mm512_unpacklo_pd(c, d));
    u[4 * q + 3] = _mm512_castpd_ps(_mm512_unpackhi_pd(c, d));
  }
  for (int j = 0; j < 4; ++j) {
    const __m512 va = _mm512_shuffle_f32x4(u[j], u[4 + j], 0x88), vb = _mm512_shuffle_f32x4(u[j], u[4 + j], 0xDD);
    const __m512 wa = _mm512_shuffle_f32x4(u[8 + j], u[12 + j], 0x88), wb = _mm512_shuffle_f32x4(u[8 + j], u[12 + j], 0xDD);
    col[j] = _mm512_shuffle_f32x4(va, wa, 0x88);
    col[8 + j] = _mm512_shuffle_f32x4(va, wa, 0xDD);
    col[4 + j] = _mm512_shuffle_f32x4(vb, wb, 0x88);
    col[12 + j] = _mm512_shuffle_f32x4(vb, wb, 0xDD);
  }
}

}  // namespace lidarsim::nn::detail::avx512
#include "nn/isa_avx512_end.h"
#endif
