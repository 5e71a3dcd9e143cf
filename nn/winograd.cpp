// See nn/winograd.h. GCC 12's AVX-512 headers trip -W(maybe-)uninitialized (as in conv3x3.cpp).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/winograd.h"

#include <algorithm>
#include <cstddef>
#include <cstdlib>
#include <new>

#include "nn/avx512_util.h"
#include "nn/big_alloc.h"
#include "nn/parallel.h"

#ifdef __AVX512F__
#include <immintrin.h>
#endif

namespace lidarsim::nn::detail {

#ifndef __AVX512F__
bool winograd_available() { return false; }
void winograd_conv3x3(const OutPlaneSet&, const PlaneSet&, const float*, int, int, int, const float*, bool,
                      const float*, bool) {}
void winograd_weight_grad(float*, const PlaneSet&, const float*, const float*, int, int, int, int, float*) {}
void winograd_backward(const OutPlaneSet&, float*, const PlaneSet&, const float*, const float*, int, int, int,
                       const float*, int, float*) {}
void winograd_transform_weights(float*, const float*, int, int, bool) {}
std::size_t winograd_u_stride(int, int) { return 0; }
#else

bool winograd_available() { return true; }

namespace {

constexpr int kCB = 8;  // output channels per GEMM register block

// Grow-only, 64-byte aligned scratch.
struct Buf {
  float* p = nullptr;
  std::size_t n = 0;
  float* get(std::size_t want) {
    if (want > n) {
      std::free(p);
      p = nullptr;  // a throw below leaves an empty buffer
      n = 0;
      p = static_cast<float*>(aligned_storage(want * sizeof(float)));
      n = want;
    }
    return p;
  }
  ~Buf() { std::free(p); }
};

Buf g_phase, g_phase_grad, g_u, g_du;
thread_local Buf tl_v, tl_m, tl_rows;

// Tile geometry. The input is kept "by phase": for each padded row (yy = y + 1) and phase r in
// 0..3, entry tx holds pixel x = 4 tx + r - 1 (zero outside the image). Input tile (ty, tx)
// covers rows 4 ty - 1 .. 4 ty + 4 and columns 4 tx - 1 .. 4 tx + 4, i.e. phases 0..3 of tile
// tx and phases 0, 1 of tile tx + 1: 16 adjacent tiles load as one unaligned vector each.
struct Geom {
  int h, w, th, tw;
  int nv;         // 16-tile vectors per block (1..3)
  int tb;         // tiles per block = 16 nv
  int blocks;     // blocks per tile row
  int len;        // floats per (row, phase) line: blocks * tb + 16
  int rows;       // padded rows: 4 th + 2
  std::size_t plane;  // floats per channel: rows * 4 * len
  Geom(int h_, int w_) : h(h_), w(w_), th((h_ + 3) / 4), tw((w_ + 3) / 4) {
    // Fewest junk tiles at the row end; ties go to the longer block (fewer weight reloads).
    int best = 3, best_waste = 1 << 30;
    for (int v = 3; v >= 1; --v) {
      const int t = 16 * v, waste = (tw + t - 1) / t * t - tw;
      if (waste < best_waste) best = v, best_waste = waste;
    }
    nv = best;
    tb = 16 * nv;
    blocks = (tw + tb - 1) / tb;
    len = blocks * tb + 16;
    rows = 4 * th + 2;
    plane = static_cast<std::size_t>(rows) * 4 * len;
  }
};

const float* plane_of(const PlaneSet& s, int img, int ch, std::size_t hw) {
  return ch < s.ca ? s.a + (static_cast<std::size_t>(img) * s.ca + ch) * hw
                   : s.b + (static_cast<std::size_t>(img) * s.cb + (ch - s.ca)) * hw;
}
float* plane_of(const OutPlaneSet& s, int img, int ch, std::size_t hw) {
  return ch < s.ca ? s.a + (static_cast<std::size_t>(img) * s.ca + ch) * hw
                   : s.b + (static_cast<std::size_t>(img) * s.cb + (ch - s.ca)) * hw;
}

// Bits [lo, hi) of a 16-lane mask, clamped to 0..16.
inline __mmask16 lane_range(int lo, int hi) {
  lo = std::max(lo, 0);
  hi = std::min(hi, 16);
  if (hi <= lo) return 0;
  return static_cast<__mmask16>(((1u << hi) - 1) & ~((1u << lo) - 1));
}

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

// Fills the by-phase layout of every (image, channel) plane, masked when mask is given; with
// sums, sums[plane] gets each plane's sum as well (to_phases_with_sum).
void to_phases(float* dst, const PlaneSet& in, const float* mask, int n, const Geom& g, float* sums = nullptr) {
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

// G = diag(1/4, -1/6, -1/6, 1/24, 1/24, 1) G' with the integer rows of G' (1 0 0), (1 1 1),
// (1 -1 1), (1 2 4), (1 -2 4), (0 0 1): G' applied to 3 values (6 adds), exact in double for
// float inputs. kGScale[a][b] = d_a d_b scales G' k G'^T into G k G^T with one rounding.
inline void g6(__m512d x0, __m512d x1, __m512d x2, __m512d y[6]) {
  const __m512d s = _mm512_add_pd(x0, x2), p = _mm512_fmadd_pd(_mm512_set1_pd(4.0), x2, x0);
  const __m512d q = _mm512_add_pd(x1, x1);
  y[0] = x0;
  y[1] = _mm512_add_pd(s, x1);
  y[2] = _mm512_sub_pd(s, x1);
  y[3] = _mm512_add_pd(p, q);
  y[4] = _mm512_sub_pd(p, q);
  y[5] = x2;
}
constexpr double kGDiv[6] = {4, -6, -6, 24, 24, 1};
struct GScale {
  double s[6][6];
  constexpr GScale() : s() {
    for (int a = 0; a < 6; ++a)
      for (int b = 0; b < 6; ++b) s[a][b] = 1.0 / (kGDiv[a] * kGDiv[b]);
  }
};
constexpr GScale kGScale;

// Floats per transform element of U: [co blocks][ci][kCB] and one cache line, so that the 36
// slices (at power-of-two strides otherwise) do not all fall into one L1 set.
inline std::size_t u_stride(int co, int ci) { return static_cast<std::size_t>((co + kCB - 1) / kCB) * kCB * ci + 16; }

// U = G k G^T for each 3x3 kernel k, packed [36][co blocks][ci][kCB] (zeros past the last output
// channel; element stride u_stride). The kCB kernels of a block ride in the 8 lanes of a double vector (gathered
// straight from the weights: staging them through memory stalled on store forwarding); each of
// the 36 results is rounded once to float and stored as kCB consecutive floats.
void transform_weights(float* u, const float* w, int co, int ci, bool transpose_flip) {
  static_assert(kCB == 8, "one double vector per block");
  const int blocks = (co + kCB - 1) / kCB;
  const std::size_t per_e = u_stride(co, ci);
  const bool par = static_cast<std::size_t>(co) * ci > 4096;
  // Lane j's tap t: w[(o ci + c) 9 + t] or, flipped, w[(c co + o) 9 + 8 - t], with o = 8 b + j.
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  constexpr int kAhead = 4;  // tasks to prefetch ahead
  const __m256i idx0 = _mm256_mullo_epi32(lane, _mm256_set1_epi32(transpose_flip ? 9 : 9 * ci));
  parallel_for(blocks * ci, par, [&](long bcl) {
    const int bc = static_cast<int>(bcl), b = bc / ci, c = bc % ci;
    if (bc + kAhead < blocks * ci) {  // the hardware prefetcher misses these jumps
      const int pb = (bc + kAhead) / ci, pc = (bc + kAhead) % ci;
      if (transpose_flip) {
        const float* p = w + (static_cast<std::size_t>(pc) * co + pb * kCB) * 9;
        for (int l = 0; l < 5; ++l) _mm_prefetch(reinterpret_cast<const char*>(p + 16 * l), _MM_HINT_T0);
      } else {
        for (int j = 0; j < kCB && pb * kCB + j < co; ++j) {
          const float* p = w + ((static_cast<std::size_t>(pb) * kCB + j) * ci + pc) * 9;
          _mm_prefetch(reinterpret_cast<const char*>(p), _MM_HINT_T0);
          _mm_prefetch(reinterpret_cast<const char*>(p + 8), _MM_HINT_T0);
        }
      }
    }
    const __mmask8 live = static_cast<__mmask8>(co - b * kCB >= kCB ? 0xff : (1u << (co - b * kCB)) - 1);
    const float* base = transpose_flip ? w + (static_cast<std::size_t>(c) * co + b * kCB) * 9 + 8
                                       : w + (static_cast<std::size_t>(b) * kCB * ci + c) * 9;
    __m512d k[9];
    for (int t = 0; t < 9; ++t) {
      const __m256i idx = _mm256_add_epi32(idx0, _mm256_set1_epi32(transpose_flip ? -t : t));
      k[t] = _mm512_cvtps_pd(_mm256_mmask_i32gather_ps(_mm256_setzero_ps(), live, idx, base, 4));
    }
    __m512d gk[3][6];  // G' k: [kw][a]
    for (int kw = 0; kw < 3; ++kw) g6(k[kw], k[3 + kw], k[6 + kw], gk[kw]);
    float* dst = u + static_cast<std::size_t>(bc) * kCB;
    for (int a = 0; a < 6; ++a) {
      __m512d r[6];
      g6(gk[0][a], gk[1][a], gk[2][a], r);
      for (int bb = 0; bb < 6; ++bb)
        _mm256_store_ps(dst + (a * 6 + bb) * per_e, _mm512_cvtpd_ps(_mm512_mul_pd(_mm512_set1_pd(kGScale.s[a][bb]), r[bb])));
    }
  });
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

// A^T applied to 6 values: the output transform's 1-D step.
inline void at6(const __m512 m[6], __m512 y[4]) {
  const __m512 s12 = _mm512_add_ps(m[1], m[2]), d12 = _mm512_sub_ps(m[1], m[2]);
  const __m512 s34 = _mm512_add_ps(m[3], m[4]), d34 = _mm512_sub_ps(m[3], m[4]);
  y[0] = _mm512_add_ps(_mm512_add_ps(m[0], s12), s34);
  y[1] = _mm512_fmadd_ps(_mm512_set1_ps(2.f), d34, d12);
  y[2] = _mm512_fmadd_ps(_mm512_set1_ps(4.f), s34, s12);
  y[3] = _mm512_add_ps(_mm512_fmadd_ps(_mm512_set1_ps(8.f), d34, d12), m[5]);
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

// V[e][c][16 lanes] for one 16-tile vector of channel c: tile row ty, first tile tx.
inline void input_tile(float* v, std::size_t e_stride, const float* plane, const Geom& g, int ty, int tx) {
  __m512 t[6][6];
  for (int i = 0; i < 6; ++i) {
    const float* row = plane + static_cast<std::size_t>(4 * ty + i) * 4 * g.len + tx;
    __m512 x[6];
    for (int k = 0; k < 6; ++k) x[k] = _mm512_loadu_ps(row + (k & 3) * g.len + (k >> 2));
    bt6(x, t[i]);
  }
  bt_columns_store(v, e_stride, t);
}

// M[co block rows][tb] = U[block][ci][kCB]^T V[ci][tb] for one transform element.
template <int NV>
inline void gemm_block(float* m, int m_stride, const float* v, int tb, const float* u, int ci) {
  __m512 acc[kCB][NV];
  for (int b = 0; b < kCB; ++b)
    for (int q = 0; q < NV; ++q) acc[b][q] = _mm512_setzero_ps();
  for (int c = 0; c < ci; ++c) {
    __m512 x[NV];
    for (int q = 0; q < NV; ++q) x[q] = _mm512_load_ps(v + static_cast<std::size_t>(c) * tb + 16 * q);
    const float* uc = u + static_cast<std::size_t>(c) * kCB;
    for (int b = 0; b < kCB; ++b) {
      const __m512 wv = _mm512_set1_ps(uc[b]);
      for (int q = 0; q < NV; ++q) acc[b][q] = _mm512_fmadd_ps(wv, x[q], acc[b][q]);
    }
  }
  for (int b = 0; b < kCB; ++b)
    for (int q = 0; q < NV; ++q) _mm512_store_ps(m + static_cast<std::size_t>(b) * m_stride + 16 * q, acc[b][q]);
}

// Writes the four vectors y[0..3] (output column j of 16 tiles) as 64 consecutive pixels.
inline void store_interleaved(float* dst, const __m512 y[4], int valid) {
  const __m512i lo = _mm512_set_epi32(23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1, 16, 0);
  const __m512i hi = _mm512_set_epi32(31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8);
  const __m512i plo = _mm512_set_epi64(11, 3, 10, 2, 9, 1, 8, 0);
  const __m512i phi = _mm512_set_epi64(15, 7, 14, 6, 13, 5, 12, 4);
  const __m512d a01l = _mm512_castps_pd(_mm512_permutex2var_ps(y[0], lo, y[1]));
  const __m512d a01h = _mm512_castps_pd(_mm512_permutex2var_ps(y[0], hi, y[1]));
  const __m512d a23l = _mm512_castps_pd(_mm512_permutex2var_ps(y[2], lo, y[3]));
  const __m512d a23h = _mm512_castps_pd(_mm512_permutex2var_ps(y[2], hi, y[3]));
  const __m512 o[4] = {_mm512_castpd_ps(_mm512_permutex2var_pd(a01l, plo, a23l)),
                       _mm512_castpd_ps(_mm512_permutex2var_pd(a01l, phi, a23l)),
                       _mm512_castpd_ps(_mm512_permutex2var_pd(a01h, plo, a23h)),
                       _mm512_castpd_ps(_mm512_permutex2var_pd(a01h, phi, a23h))};
  for (int q = 0; q < 4 && valid > 0; ++q, valid -= 16) {
    if (valid >= 16)
      _mm512_storeu_ps(dst + 16 * q, o[q]);
    else
      _mm512_mask_storeu_ps(dst + 16 * q, static_cast<__mmask16>((1u << valid) - 1), o[q]);
  }
}

// Output tiles of one channel for one 16-tile vector: A^T M A, bias, ReLU, written to out.
inline void output_tile(float* out_plane, const float* m, std::size_t e_stride, const Geom& g, int ty, int tx,
                        float bias, bool relu) {
  __m512 t[6][4];
  for (int a = 0; a < 6; ++a) {
    __m512 row[6];
    for (int bb = 0; bb < 6; ++bb) row[bb] = _mm512_load_ps(m + (a * 6 + bb) * e_stride);
    at6(row, t[a]);
  }
  const __m512 bv = _mm512_set1_ps(bias), zero = _mm512_setzero_ps();
  const int x0 = 4 * tx, valid = std::min(64, g.w - x0);
  if (valid <= 0) return;
  __m512 y[4][4];
  for (int j = 0; j < 4; ++j) {
    __m512 col[6], r[4];
    for (int a = 0; a < 6; ++a) col[a] = t[a][j];
    at6(col, r);
    for (int i = 0; i < 4; ++i) y[i][j] = relu ? _mm512_max_ps(_mm512_add_ps(r[i], bv), zero) : _mm512_add_ps(r[i], bv);
  }
  for (int i = 0; i < 4; ++i) {
    const int yrow = 4 * ty + i;
    if (yrow >= g.h) break;
    store_interleaved(out_plane + static_cast<std::size_t>(yrow) * g.w + x0, y[i], valid);
  }
}

template <int NV>
void run(const OutPlaneSet& out, const float* phases, int n, int ci, const Geom& g, const float* u, const float* bias,
         bool relu) {
  const int co = out.ca + out.cb;
  const int co_blocks = (co + kCB - 1) / kCB;
  const std::size_t u_e = u_stride(co, ci);
  const int tiles_tasks = n * g.th * g.blocks;
  const int threads = team_threads();
  // Few tile blocks (the deep layers): split the output channels too, each part repeating the
  // (cheap) input transform, so every thread has work.
  int parts = 1;
  if (tiles_tasks < 4 * threads) parts = std::min(co_blocks, (4 * threads + tiles_tasks - 1) / tiles_tasks);
  const int tasks = tiles_tasks * parts;
  const double flops = 2.0 * tiles_tasks * g.tb * 36.0 * ci * co;
  const std::size_t hw = static_cast<std::size_t>(g.h) * g.w;
  parallel_shared(tasks, flops > 2e6, [&](int tid, int nt, Shares& shares) {
    // One cache line past each transform element's slice: power-of-two strides would put the 36
    // slices of a tile in one L1 set.
    const std::size_t v_e = static_cast<std::size_t>(ci) * g.tb + 16;
    float* v = tl_v.get(36 * v_e);
    shares.run(tid, nt, [&](long tl) {
      const int task = static_cast<int>(tl), part = task % parts, tt = task / parts;
      const int img = tt / (g.th * g.blocks), ty = (tt / g.blocks) % g.th, blk = tt % g.blocks;
      const int b0 = co_blocks * part / parts, b1 = co_blocks * (part + 1) / parts;
      const std::size_t m_e = static_cast<std::size_t>(b1 - b0) * kCB * g.tb + 16;
      float* m = tl_m.get(36 * m_e);
      for (int c = 0; c < ci; ++c) {
        const float* plane = phases + (static_cast<std::size_t>(img) * ci + c) * g.plane;
        for (int q = 0; q < NV; ++q)
          input_tile(v + static_cast<std::size_t>(c) * g.tb + 16 * q, v_e, plane, g, ty, blk * g.tb + 16 * q);
      }
      for (int e = 0; e < 36; ++e)
        for (int b = b0; b < b1; ++b)
          gemm_block<NV>(m + e * m_e + static_cast<std::size_t>(b - b0) * kCB * g.tb, g.tb, v + e * v_e, g.tb,
                         u + e * u_e + static_cast<std::size_t>(b) * ci * kCB, ci);
      for (int o = b0 * kCB; o < std::min(co, b1 * kCB); ++o) {
        float* op = plane_of(out, img, o, hw);
        const float* mo = m + static_cast<std::size_t>(o - b0 * kCB) * g.tb;
        for (int q = 0; q < NV; ++q)
          output_tile(op, mo + 16 * q, m_e, g, ty, blk * g.tb + 16 * q, bias ? bias[o] : 0.f, relu);
      }
    });
  });
}

// A applied to 4 values (the transpose of at6): the output gradient's 1-D step.
inline void a4(const __m512 y[4], __m512 m[6]) {
  const __m512 s02 = _mm512_add_ps(y[0], y[2]), s13 = _mm512_add_ps(y[1], y[3]);
  const __m512 t02 = _mm512_fmadd_ps(_mm512_set1_ps(4.f), y[2], y[0]);
  const __m512 t13 = _mm512_fmadd_ps(_mm512_set1_ps(8.f), y[3], _mm512_mul_ps(_mm512_set1_ps(2.f), y[1]));
  m[0] = y[0];
  m[1] = _mm512_add_ps(s02, s13);
  m[2] = _mm512_sub_ps(s02, s13);
  m[3] = _mm512_add_ps(t02, t13);
  m[4] = _mm512_sub_ps(t02, t13);
  m[5] = y[3];
}

// dM[e][16 lanes] = (A dY A^T)[e] for one 16-tile vector of one output-gradient channel, read
// from its by-phase layout: output pixel (4 ty + i, 4 tx + j) is padded row 4 ty + 1 + i,
// phase (j + 1) & 3 of tile tx + (j + 1) / 4.
inline void grad_tile(float* m, std::size_t e_stride, const float* plane, const Geom& g, int ty, int tx) {
  __m512 t[4][6];
  for (int i = 0; i < 4; ++i) {
    const float* row = plane + static_cast<std::size_t>(4 * ty + 1 + i) * 4 * g.len + tx;
    __m512 y[4];
    for (int j = 0; j < 4; ++j) y[j] = _mm512_loadu_ps(row + ((j + 1) & 3) * g.len + ((j + 1) >> 2));
    a4(y, t[i]);
  }
  for (int b = 0; b < 6; ++b) {
    __m512 col[4], r[6];
    for (int i = 0; i < 4; ++i) col[i] = t[i][b];
    a4(col, r);
    for (int a = 0; a < 6; ++a) _mm512_store_ps(m + (a * 6 + b) * e_stride, r[a]);
  }
}

// The weight gradient streams the tiles in chunks (one image, one tile row, up to 128 tiles): no
// buffer holds every tile's transforms. The input tiles are transformed with 16 channels per
// vector, from a copy of the chunk's 6 input rows with the channels interleaved; the
// output-gradient tiles with 16 tiles per vector (grad_tile). Per transform element the product
// is then a GEMM over the chunk's tiles whose result block stays in registers: no horizontal sums.

// rows [cgs][6][cols][16]: input rows 4 ty - 1 .. 4 ty + 4, columns 4 t0 - 1 + j (j < cols, a
// multiple of 16), channel 16 group + lane; zeros outside the image and past the last channel.
void interleave_rows(float* rows, int cols, const PlaneSet& in, int img, const Geom& g, int ty, int t0) {
  const int ci = in.ca + in.cb, cgs = (ci + 15) / 16;
  const std::size_t hw = static_cast<std::size_t>(g.h) * g.w;
  const __m512 zero = _mm512_setzero_ps();
  for (int cg = 0; cg < cgs; ++cg) {
    const float* planes[16];
    for (int l = 0; l < 16; ++l) planes[l] = 16 * cg + l < ci ? plane_of(in, img, 16 * cg + l, hw) : nullptr;
    for (int i = 0; i < 6; ++i) {
      float* dst = rows + (static_cast<std::size_t>(cg) * 6 + i) * cols * 16;
      const int y = 4 * ty - 1 + i;
      if (y < 0 || y >= g.h) {
        std::fill(dst, dst + static_cast<std::size_t>(cols) * 16, 0.f);
        continue;
      }
      for (int j0 = 0; j0 < cols; j0 += 16) {
        const int x0 = 4 * t0 - 1 + j0;
        const __mmask16 k = lane_range(-x0, g.w - x0);
        __m512 r[16], col[16];
        for (int l = 0; l < 16; ++l)
          r[l] = planes[l] && k ? _mm512_maskz_loadu_ps(k, planes[l] + static_cast<std::size_t>(y) * g.w + x0) : zero;
        transpose16(r, col);
        for (int p = 0; p < 16; ++p) _mm512_store_ps(dst + static_cast<std::size_t>(j0 + p) * 16, col[p]);
      }
    }
  }
}

// V[e][16 channels] of chunk tile t from one channel group's interleaved rows (as input_tile,
// with channels in the lanes instead of tiles).
inline void input_tile_interleaved(float* v, std::size_t e_stride, const float* rows, int cols, int t) {
  __m512 tr[6][6];
  for (int i = 0; i < 6; ++i) {
    const float* row = rows + (static_cast<std::size_t>(i) * cols + 4 * t) * 16;
    __m512 x[6];
    for (int k = 0; k < 6; ++k) x[k] = _mm512_load_ps(row + 16 * k);
    bt6(x, tr[i]);
  }
  bt_columns_store(v, e_stride, tr);
}

// du[OB rows][16 CV channels] += sum over tiles t < tiles of dm[row][t] v[t][channels]: the
// OB x CV accumulators stay in registers while the tiles stream past.
template <int OB, int CV>
inline void du_block(float* du, std::size_t du_row, const float* dm, std::size_t dm_row, const float* v,
                     std::size_t v_row, int tiles) {
  __m512 acc[OB][CV];
  for (int b = 0; b < OB; ++b)
    for (int q = 0; q < CV; ++q) acc[b][q] = _mm512_load_ps(du + b * du_row + 16 * q);
  for (int t = 0; t < tiles; ++t) {
    __m512 x[CV];
    for (int q = 0; q < CV; ++q) x[q] = _mm512_load_ps(v + t * v_row + 16 * q);
    for (int b = 0; b < OB; ++b) {
      const __m512 gv = _mm512_set1_ps(dm[b * dm_row + t]);
      for (int q = 0; q < CV; ++q) acc[b][q] = _mm512_fmadd_ps(gv, x[q], acc[b][q]);
    }
  }
  for (int b = 0; b < OB; ++b)
    for (int q = 0; q < CV; ++q) _mm512_store_ps(du + b * du_row + 16 * q, acc[b][q]);
}

}  // namespace

namespace {

// The conv of winograd_conv3x3 from the by-phase copy of its input (ci channels).
void conv_from_phases(const OutPlaneSet& out, const float* phases, int ci, int n, const Geom& g, const float* weight,
                      bool transpose_flip, const float* bias, bool relu) {
  const int co = out.ca + out.cb;
  // Per call, even in predict(): cached per layer (nn/weight_cache.h), four times the weights
  // came back from memory at the cost the transform saved (tried, no gain).
  float* u = g_u.get(36 * u_stride(co, ci));
  transform_weights(u, weight, co, ci, transpose_flip);
  if (g.nv == 3)
    run<3>(out, phases, n, ci, g, u, bias, relu);
  else if (g.nv == 2)
    run<2>(out, phases, n, ci, g, u, bias, relu);
  else
    run<1>(out, phases, n, ci, g, u, bias, relu);
}

void weight_grad_streaming(float* d_weight, const PlaneSet& in, const float* pg, int co, int n, const Geom& g);

}  // namespace

void winograd_conv3x3(const OutPlaneSet& out, const PlaneSet& in, const float* mask, int n, int h, int w,
                      const float* weight, bool transpose_flip, const float* bias, bool relu) {
  const Geom g(h, w);
  const int ci = in.ca + in.cb;
  float* phases = g_phase.get(static_cast<std::size_t>(n) * ci * g.plane);
  to_phases(phases, in, mask, n, g);
  conv_from_phases(out, phases, ci, n, g, weight, transpose_flip, bias, relu);
}

std::size_t winograd_u_stride(int co, int ci) { return u_stride(co, ci); }

void winograd_transform_weights(float* u, const float* weight, int co, int ci, bool transpose_flip) {
  transform_weights(u, weight, co, ci, transpose_flip);
}

namespace {
// The weight gradient from the input and a by-phase copy of the masked output gradient; returns
// the latter, which the input gradient reads too.
const float* weight_grad_via_phases(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n,
                                    int co, const Geom& g, float* sums) {
  float* pg = g_phase_grad.get(static_cast<std::size_t>(n) * co * g.plane);
  to_phases(pg, PlaneSet{d_out, co}, mask, n, g, sums);
  weight_grad_streaming(d_weight, in, pg, co, n, g);
  return pg;
}
}  // namespace

void winograd_weight_grad(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n, int h,
                          int w, int co, float* sums) {
  weight_grad_via_phases(d_weight, in, d_out, mask, n, co, Geom(h, w), sums);
}

void winograd_backward(const OutPlaneSet& d_in, float* d_weight, const PlaneSet& in, const float* d_out,
                       const float* mask, int n, int h, int w, const float* weight, int co, float* sums) {
  const Geom g(h, w);
  const float* pg = weight_grad_via_phases(d_weight, in, d_out, mask, n, co, g, sums);
  conv_from_phases(d_in, pg, co, n, g, weight, true, nullptr, false);
}

namespace {

#ifndef LIDARSIM_WG_L2_FLOATS
#define LIDARSIM_WG_L2_FLOATS 393216
#endif
// A chunk's transformed tiles (V and dM) take up to 1.5 MB, more than L2: longer chunks cut the
// traffic of the partial sums (read and written once per chunk) by more than the tiles' misses
// cost. One thread, batch-4 step: 0.243-0.246 s with 384 KB, 0.234-0.244 s with 768 KB,
// 0.231-0.239 s with 1.5 MB, the same with 3 MB.
constexpr int kChunkFloats = LIDARSIM_WG_L2_FLOATS;
constexpr int kMaxSlots = 8;                         // partial sums of the tiles, added in order at the end
constexpr std::size_t kSlotFloats = std::size_t{1} << 22;  // all slots' partial sums: at most 16 MB

void weight_grad_streaming(float* d_weight, const PlaneSet& in, const float* pg, int co, int n, const Geom& g) {
  const int ci = in.ca + in.cb, cgs = (ci + 15) / 16, ci16 = 16 * cgs;
  const int co8 = (co + kCB - 1) / kCB * kCB, ob = co8 / kCB;
  const int span = (g.tw + 15) / 16 * 16;  // tiles per tile row, whole 16-tile vectors
  const int tile_cap = std::max(16, kChunkFloats / (36 * (ci16 + co8)) / 16 * 16);
  const int chunk = std::min({span, tile_cap, 128});
  const int per_row = (span + chunk - 1) / chunk;
  const long chunks = static_cast<long>(n) * g.th * per_row;
  // The slots (contiguous runs of chunks, each summed in order into its own partial dU) depend
  // on the shapes only, so the result does not depend on the thread count. Output-channel parts
  // (each repeating the cheap input transform) give the deep layers, with few tiles, more tasks.
  const std::size_t du_floats = static_cast<std::size_t>(36) * co8 * ci16;
  const int slots = static_cast<int>(
      std::max<long>(1, std::min<long>({chunks, kMaxSlots, static_cast<long>(kSlotFloats / du_floats)})));
  const int want = 4 * team_threads();
  const int parts = slots >= want ? 1 : std::min(ob, (want + slots - 1) / slots);
  const double flops = 2.0 * 36 * static_cast<double>(chunks) * chunk * ci * co;
  const bool par = flops > 2e6;
  float* du = g_du.get(slots * du_floats);
  const int cols = (4 * chunk + 2 + 15) / 16 * 16;
  const std::size_t v_e = static_cast<std::size_t>(chunk) * ci16 + 16;
  parallel_shared(slots * parts, par, [&](int tid, int nt, Shares& shares) {
    float* rows = tl_rows.get(static_cast<std::size_t>(cgs) * 6 * cols * 16);
    float* v = tl_v.get(36 * v_e);
    shares.run(tid, nt, [&](long task) {
      const int s = static_cast<int>(task / parts), p = static_cast<int>(task % parts);
      const int o0 = kCB * (ob * p / parts), o1 = kCB * (ob * (p + 1) / parts), orows = o1 - o0;
      const std::size_t m_e = static_cast<std::size_t>(orows) * chunk + 16;
      float* m = tl_m.get(36 * m_e);
      float* dus = du + s * du_floats;
      for (int e = 0; e < 36; ++e) {
        std::fill(dus + (static_cast<std::size_t>(e) * co8 + o0) * ci16, dus + (static_cast<std::size_t>(e) * co8 + o1) * ci16,
                  0.f);
        for (int o = std::max(co, o0); o < o1; ++o)  // the block's rows past the last channel
          std::fill(m + e * m_e + static_cast<std::size_t>(o - o0) * chunk,
                    m + e * m_e + static_cast<std::size_t>(o - o0 + 1) * chunk, 0.f);
      }
      const long c_begin = chunks * s / slots, c_end = chunks * (s + 1) / slots;
      for (long c = c_begin; c < c_end; ++c) {
        const int img = static_cast<int>(c / (static_cast<long>(g.th) * per_row));
        const int ty = static_cast<int>(c / per_row % g.th), t0 = static_cast<int>(c % per_row) * chunk;
        const int tiles = std::min(chunk, span - t0);
        interleave_rows(rows, cols, in, img, g, ty, t0);
        for (int t = 0; t < tiles; ++t)
          for (int cg = 0; cg < cgs; ++cg)
            input_tile_interleaved(v + static_cast<std::size_t>(t) * ci16 + 16 * cg, v_e,
                                   rows + static_cast<std::size_t>(cg) * 6 * cols * 16, cols, t);
        for (int o = o0; o < std::min(co, o1); ++o)
          for (int q = 0; q < tiles; q += 16)
            grad_tile(m + static_cast<std::size_t>(o - o0) * chunk + q, m_e,
                      pg + (static_cast<std::size_t>(img) * co + o) * g.plane, g, ty, t0 + q);
        for (int e = 0; e < 36; ++e)
          for (int o = o0; o < o1; o += kCB) {
            float* d = dus + (static_cast<std::size_t>(e) * co8 + o) * ci16;
            const float* dm = m + e * m_e + static_cast<std::size_t>(o - o0) * chunk;
            const float* ve = v + e * v_e;
            int c16 = 0;
            for (; c16 + 32 <= ci16; c16 += 32) du_block<kCB, 2>(d + c16, ci16, dm, chunk, ve + c16, ci16, tiles);
            if (c16 < ci16) du_block<kCB, 1>(d + c16, ci16, dm, chunk, ve + c16, ci16, tiles);
          }
      }
    });
  });
  // dU = the slots' partial sums, added in slot order.
  if (slots > 1)
    parallel_for((du_floats + 1023) / 1024, par, [&](long blk) {
      const std::size_t i0 = static_cast<std::size_t>(blk) * 1024, i1 = std::min(du_floats, i0 + 1024);
      for (int s = 1; s < slots; ++s) {
        const float* src = du + s * du_floats;
        for (std::size_t i = i0; i < i1; ++i) du[i] += src[i];
      }
    });

  // d_weight += G^T dU G per kernel, in double: 8 input channels in the lanes of a double vector
  // (contiguous in dU), each lane doing the scalar sums in their order (multiply, then add; no
  // FMA), so the result is the same bits as one kernel at a time.
  static constexpr double G[6][3] = {{1.0 / 4, 0, 0},
                                     {-1.0 / 6, -1.0 / 6, -1.0 / 6},
                                     {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                     {1.0 / 24, 1.0 / 12, 1.0 / 6},
                                     {1.0 / 24, -1.0 / 12, 1.0 / 6},
                                     {0, 0, 1}};
  const std::size_t du_e = static_cast<std::size_t>(co8) * ci16;
  const int c_blocks = (ci + 7) / 8;
  parallel_for(co * c_blocks, par, [&](long ocl) {
    const int oc = static_cast<int>(ocl), o = oc / c_blocks, c0 = oc % c_blocks * 8, nc = std::min(8, ci - c0);
    const __mmask8 live = static_cast<__mmask8>(nc == 8 ? 0xff : (1u << nc) - 1);
    const float* d = du + static_cast<std::size_t>(o) * ci16 + c0;
    __m512d t[6][3];  // dU G
    for (int a = 0; a < 6; ++a) {
      __m512d x[6];
      for (int bb = 0; bb < 6; ++bb) x[bb] = _mm512_cvtps_pd(_mm256_maskz_loadu_ps(live, d + (a * 6 + bb) * du_e));
      for (int kw = 0; kw < 3; ++kw) {
        __m512d acc = _mm512_setzero_pd();
        for (int bb = 0; bb < 6; ++bb) acc = _mm512_add_pd(acc, _mm512_mul_pd(x[bb], _mm512_set1_pd(G[bb][kw])));
        t[a][kw] = acc;
      }
    }
    alignas(64) double r[9][8];
    for (int kh = 0; kh < 3; ++kh)
      for (int kw = 0; kw < 3; ++kw) {
        __m512d acc = _mm512_setzero_pd();
        for (int a = 0; a < 6; ++a) acc = _mm512_add_pd(acc, _mm512_mul_pd(_mm512_set1_pd(G[a][kh]), t[a][kw]));
        _mm512_store_pd(r[kh * 3 + kw], acc);
      }
    for (int j = 0; j < nc; ++j) {
      float* dw = d_weight + (static_cast<std::size_t>(o) * ci + c0 + j) * 9;
      for (int k = 0; k < 9; ++k) dw[k] += static_cast<float>(r[k][j]);
    }
  });
}


}  // namespace

#endif

}  // namespace lidarsim::nn::detail
