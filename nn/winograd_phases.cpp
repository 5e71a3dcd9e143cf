// The by-phase layout of nn/winograd_tiles.h: each plane copied once, with its sum on the way
// when the bias gradient needs it. GCC 12's AVX-512 headers trip -W(maybe-)uninitialized (as in
// conv3x3.cpp).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/winograd_tiles.h"

#if LIDARSIM_AVX512_KERNELS
#include <algorithm>
#include <cstddef>

#include "nn/avx512_util.h"
#include "nn/parallel.h"

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512::wino {

namespace {

#ifndef LIDARSIM_PHASE_PREFETCH
#define LIDARSIM_PHASE_PREFETCH 256
#endif
constexpr int kPhasePrefetch = LIDARSIM_PHASE_PREFETCH;  // source floats to prefetch ahead in to_phases (0: none)

// The 64 source pixels of one by-phase piece (row s, tiles tx .. tx + 15; zero outside the row
// and, with mask, where mask <= 0) into a[4], 16 consecutive pixels each.
inline void load_piece(__m512 a[4], const float* s, const float* mr, const Geom& g, int tx) {
  const __m512 zero = _mm512_setzero_ps();
  if (kPhasePrefetch) {
    const char* ahead = reinterpret_cast<const char*>(s + 4 * tx + kPhasePrefetch);
    for (int l = 0; l < 4; ++l) _mm_prefetch(ahead + 64 * l, _MM_HINT_T0);
    if (mr)
      for (int l = 0; l < 4; ++l)
        _mm_prefetch(reinterpret_cast<const char*>(mr + 4 * tx + kPhasePrefetch) + 64 * l, _MM_HINT_T0);
  }
  for (int q = 0; q < 4; ++q) {
    const int x = 4 * tx - 1 + 16 * q;  // pixel of lane 0
    __mmask16 k = lane_range(-x, g.w - x);
    if (mr && k) k &= _mm512_cmp_ps_mask(_mm512_maskz_loadu_ps(k, mr + x), zero, _CMP_GT_OQ);
    a[q] = k ? _mm512_maskz_loadu_ps(k, s + x) : zero;
  }
}

// Splits a piece into the 4 phases of 16 tiles (two permutes) and stores them in a padded row.
inline void store_phases(float* line, const Geom& g, int tx, const __m512 a[4]) {
  const __m512i even = _mm512_set_epi32(30, 26, 22, 18, 14, 10, 6, 2, 28, 24, 20, 16, 12, 8, 4, 0);
  const __m512i odd = _mm512_set_epi32(31, 27, 23, 19, 15, 11, 7, 3, 29, 25, 21, 17, 13, 9, 5, 1);
  // Lanes 0..7 phase 0 (1), lanes 8..15 phase 2 (3), of pixels 0..31 and 32..63.
  const __m512 e01 = _mm512_permutex2var_ps(a[0], even, a[1]), e23 = _mm512_permutex2var_ps(a[2], even, a[3]);
  const __m512 o01 = _mm512_permutex2var_ps(a[0], odd, a[1]), o23 = _mm512_permutex2var_ps(a[2], odd, a[3]);
  _mm512_storeu_ps(line + tx, _mm512_shuffle_f32x4(e01, e23, 0x44));
  _mm512_storeu_ps(line + g.len + tx, _mm512_shuffle_f32x4(o01, o23, 0x44));
  _mm512_storeu_ps(line + 2 * g.len + tx, _mm512_shuffle_f32x4(e01, e23, 0xEE));
  _mm512_storeu_ps(line + 3 * g.len + tx, _mm512_shuffle_f32x4(o01, o23, 0xEE));
}

// One plane into the by-phase layout, and its sum (of the masked values) in the plain order of
// the bias gradient (nn/conv3x3.cpp plane_sum: each row from x = 0 up, the row sums added from
// y = 0 down; the zeros of the layout's borders change no sum). 16 rows are split side by side,
// their pieces kept in L1 and transposed so that each row's chain of adds runs in one lane: the
// plane is read once for both.
float to_phases_with_sum(float* d, const float* src, const float* m, const Geom& g) {
  std::fill(d, d + 4 * g.len, 0.f);  // padded row 0
  std::fill(d + static_cast<std::size_t>(g.h + 1) * 4 * g.len, d + g.plane, 0.f);
  float total = 0.f;
  alignas(64) float piece[16][64];
  for (int y0 = 0; y0 < g.h; y0 += 16) {
    const int nr = std::min(16, g.h - y0);
    if (nr < 16) std::fill(&piece[0][0], &piece[0][0] + 16 * 64, 0.f);  // lanes that are dropped
    __m512 acc = _mm512_setzero_ps();
    for (int tx = 0; tx < g.len; tx += 16) {
      for (int r = 0; r < nr; ++r) {
        const std::size_t y = static_cast<std::size_t>(y0 + r);
        __m512 a[4];
        load_piece(a, src + y * g.w, m ? m + y * g.w : nullptr, g, tx);
        store_phases(d + (y + 1) * 4 * g.len, g, tx, a);
        for (int q = 0; q < 4; ++q) _mm512_store_ps(piece[r] + 16 * q, a[q]);
      }
      for (int q = 0; q < 4; ++q) {
        __m512 rows[16], col[16];
        for (int k = 0; k < 16; ++k) rows[k] = _mm512_load_ps(piece[k] + 16 * q);
        transpose16(rows, col);
        for (int x = 0; x < 16; ++x) acc = _mm512_add_ps(acc, col[x]);
      }
    }
    alignas(64) float rs[16];
    _mm512_store_ps(rs, acc);
    for (int k = 0; k < nr; ++k) total += rs[k];
  }
  return total;
}


}  // namespace

void to_phases(float* dst, const PlaneSet& in, const float* mask, int n, const Geom& g, float* sums) {
  const int ci = in.ca + in.cb;
  const std::size_t hw = static_cast<std::size_t>(g.h) * g.w;
  const bool par = static_cast<std::size_t>(n) * ci * hw > (1u << 15);
  parallel_for(n * ci, par, [&](long p) {
    const int img = static_cast<int>(p / ci), ch = static_cast<int>(p % ci);
    const float* src = plane_of(in, img, ch, hw);
    const float* m = mask ? mask + static_cast<std::size_t>(p) * hw : nullptr;
    float* d = dst + static_cast<std::size_t>(p) * g.plane;
    if (sums) {
      sums[p] = to_phases_with_sum(d, src, m, g);
      return;
    }
    for (int yy = 0; yy < g.rows; ++yy) {
      float* line = d + static_cast<std::size_t>(yy) * 4 * g.len;
      const int y = yy - 1;
      if (y < 0 || y >= g.h) {
        std::fill(line, line + 4 * g.len, 0.f);
        continue;
      }
      const float* s = src + static_cast<std::size_t>(y) * g.w;
      const float* mr = m ? m + static_cast<std::size_t>(y) * g.w : nullptr;
      for (int tx = 0; tx < g.len; tx += 16) {
        __m512 a[4];
        load_piece(a, s, mr, g, tx);
        store_phases(line, g, tx, a);
      }
    }
  });
}

}  // namespace lidarsim::nn::detail::avx512::wino
#include "nn/isa_avx512_end.h"

#endif
