// See nn/winograd.h: the forward convolution (weight transform, input transform, the 36 GEMMs,
// output transform). The weight gradient is in nn/winograd_weight_grad.cpp. GCC 12's AVX-512
// headers trip -W(maybe-)uninitialized (as in conv3x3.cpp).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/winograd.h"

#include <algorithm>
#include <cstddef>

#include "nn/cpu_features.h"
#include "nn/parallel.h"
#include "nn/winograd_tiles.h"

namespace lidarsim::nn::detail {

bool winograd_available() { return LIDARSIM_AVX2_KERNELS || isa_at_least(Isa::avx512); }

namespace {
bool wide() { return isa_at_least(Isa::avx512); }
}  // namespace

void winograd_conv3x3(const OutPlaneSet& out, const PlaneSet& in, const float* mask, int n, int h, int w,
                      const float* weight, bool transpose_flip, const float* bias, bool relu) {
  if (wide())
    avx512::winograd_conv3x3(out, in, mask, n, h, w, weight, transpose_flip, bias, relu);
  else
    avx2::winograd_conv3x3(out, in, mask, n, h, w, weight, transpose_flip, bias, relu);
}

void winograd_backward(const OutPlaneSet& d_in, float* d_weight, const PlaneSet& in, const float* d_out,
                       const float* mask, int n, int h, int w, const float* weight, int co, float* sums) {
  if (wide())
    avx512::winograd_backward(d_in, d_weight, in, d_out, mask, n, h, w, weight, co, sums);
  else
    avx2::winograd_backward(d_in, d_weight, in, d_out, mask, n, h, w, weight, co, sums);
}

std::size_t winograd_u_stride(int co, int ci) {
  return wide() ? avx512::winograd_u_stride(co, ci) : avx2::winograd_u_stride(co, ci);
}

void winograd_transform_weights(float* u, const float* weight, int co, int ci, bool transpose_flip) {
  if (wide())
    avx512::winograd_transform_weights(u, weight, co, ci, transpose_flip);
  else
    avx2::winograd_transform_weights(u, weight, co, ci, transpose_flip);
}

void winograd_weight_grad(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n, int h,
                          int w, int co, float* sums) {
  if (wide())
    avx512::winograd_weight_grad(d_weight, in, d_out, mask, n, h, w, co, sums);
  else
    avx2::winograd_weight_grad(d_weight, in, d_out, mask, n, h, w, co, sums);
}

}  // namespace lidarsim::nn::detail

#if !LIDARSIM_AVX512_KERNELS
namespace lidarsim::nn::detail::avx512 {
void winograd_conv3x3(const OutPlaneSet&, const PlaneSet&, const float*, int, int, int, const float*, bool,
                      const float*, bool) {}
void winograd_transform_weights(float*, const float*, int, int, bool) {}
std::size_t winograd_u_stride(int, int) { return 0; }
}  // namespace lidarsim::nn::detail::avx512
#else

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512 {

namespace wino {
thread_local Buf tl_v, tl_m;
}  // namespace wino

using namespace wino;

namespace {

// Scratch of one call, per calling thread: pure caches (models running in several threads at
// once must not share them); the team's workers get the pointers.
thread_local Buf tl_phase, tl_u;

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

// A^T applied to 6 values: the output transform's 1-D step.
inline void at6(const __m512 m[6], __m512 y[4]) {
  const __m512 s12 = _mm512_add_ps(m[1], m[2]), d12 = _mm512_sub_ps(m[1], m[2]);
  const __m512 s34 = _mm512_add_ps(m[3], m[4]), d34 = _mm512_sub_ps(m[3], m[4]);
  y[0] = _mm512_add_ps(_mm512_add_ps(m[0], s12), s34);
  y[1] = _mm512_fmadd_ps(_mm512_set1_ps(2.f), d34, d12);
  y[2] = _mm512_fmadd_ps(_mm512_set1_ps(4.f), s34, s12);
  y[3] = _mm512_add_ps(_mm512_fmadd_ps(_mm512_set1_ps(8.f), d34, d12), m[5]);
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

}  // namespace

namespace wino {

// The conv of winograd_conv3x3 from the by-phase copy of its input (ci channels).
void conv_from_phases(const OutPlaneSet& out, const float* phases, int ci, int n, const Geom& g, const float* weight,
                      bool transpose_flip, const float* bias, bool relu) {
  const int co = out.ca + out.cb;
  // Per call, even in predict(): a per-layer cache (nn/weight_cache.h) would bring four times
  // the weights back from memory, costing what the transform saves.
  float* u = tl_u.get(36 * u_stride(co, ci));
  transform_weights(u, weight, co, ci, transpose_flip);
  if (g.nv == 3)
    run<3>(out, phases, n, ci, g, u, bias, relu);
  else if (g.nv == 2)
    run<2>(out, phases, n, ci, g, u, bias, relu);
  else
    run<1>(out, phases, n, ci, g, u, bias, relu);
}

}  // namespace wino

void winograd_conv3x3(const OutPlaneSet& out, const PlaneSet& in, const float* mask, int n, int h, int w,
                      const float* weight, bool transpose_flip, const float* bias, bool relu) {
  const Geom g(h, w);
  const int ci = in.ca + in.cb;
  float* phases = tl_phase.get(static_cast<std::size_t>(n) * ci * g.plane);
  to_phases(phases, in, mask, n, g);
  conv_from_phases(out, phases, ci, n, g, weight, transpose_flip, bias, relu);
}

std::size_t winograd_u_stride(int co, int ci) { return u_stride(co, ci); }

void winograd_transform_weights(float* u, const float* weight, int co, int ci, bool transpose_flip) {
  transform_weights(u, weight, co, ci, transpose_flip);
}

}  // namespace lidarsim::nn::detail::avx512
#include "nn/isa_avx512_end.h"

#endif
