// The AVX2 port of the Winograd F(4x4, 3x3) forward pass (nn/winograd.h, namespace avx2): the
// structure of nn/winograd.cpp with 8-lane vectors. Weight transform, by-phase copy of the input,
// input transform, the 36 channel GEMMs, output transform with bias and ReLU. The weight gradient
// is in nn/winograd_avx2_weight_grad.cpp.
#include "nn/winograd_avx2.h"

#include <algorithm>
#include <cstddef>
#include <vector>

#include "nn/parallel.h"

#if !LIDARSIM_AVX2_KERNELS
namespace lidarsim::nn::detail::avx2 {
void winograd_conv3x3(const OutPlaneSet&, const PlaneSet&, const float*, int, int, int, const float*, bool,
                      const float*, bool) {}
void winograd_transform_weights(float*, const float*, int, int, bool) {}
std::size_t winograd_u_stride(int, int) { return 0; }
}  // namespace lidarsim::nn::detail::avx2
#else

namespace lidarsim::nn::detail::avx2 {

namespace wino {
thread_local Buf tl_v, tl_m;
}  // namespace wino

using namespace wino;

namespace {

// Scratch of one call, per calling thread (models running in several threads at once must not
// share it); the team's workers get the pointers.
thread_local Buf tl_phase, tl_u;
// One padded source row of to_phases, per team thread.
thread_local std::vector<float> tl_row;

// G = diag(1/4, -1/6, -1/6, 1/24, 1/24, 1) G' with the integer rows of G' (1 0 0), (1 1 1),
// (1 -1 1), (1 2 4), (1 -2 4), (0 0 1): G' applied to 3 values, exact in double for float
// inputs; kGScale[a][b] = d_a d_b scales G' k G'^T into G k G^T with one rounding. The same
// arithmetic as the AVX-512 transform (nn/winograd.cpp; 4 x2 is exact, so its FMA rounds as the
// add here): the same bits.
inline void g6(__m256d x0, __m256d x1, __m256d x2, __m256d y[6]) {
  const __m256d s = _mm256_add_pd(x0, x2), p = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(4.0), x2), x0);
  const __m256d q = _mm256_add_pd(x1, x1);
  y[0] = x0;
  y[1] = _mm256_add_pd(s, x1);
  y[2] = _mm256_sub_pd(s, x1);
  y[3] = _mm256_add_pd(p, q);
  y[4] = _mm256_sub_pd(p, q);
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

// Floats per transform element of U: [co blocks][ci][kCB] and one cache line (the 36 slices at
// power-of-two strides would share one L1 set).
inline std::size_t u_stride(int co, int ci) { return static_cast<std::size_t>((co + kCB - 1) / kCB) * kCB * ci + 16; }

// U = G k G^T for each 3x3 kernel k, packed [36][co blocks][ci][kCB] (zeros past the last output
// channel; element stride u_stride). transpose_flip: the weight is [ci][co][3][3], read flipped.
// Four output channels ride in the lanes of a double vector, gathered from the weights.
void transform_weights(float* u, const float* w, int co, int ci, bool transpose_flip) {
  const int blocks = (co + kCB - 1) / kCB;
  const std::size_t per_e = u_stride(co, ci);
  // Lane j's tap t: w[(o ci + c) 9 + t] or, flipped, w[(c co + o) 9 + 8 - t], with o = o0 + j.
  const __m128i idx0 = _mm_mullo_epi32(_mm_setr_epi32(0, 1, 2, 3), _mm_set1_epi32(transpose_flip ? 9 : 9 * ci));
  parallel_for(blocks * ci, static_cast<std::size_t>(co) * ci > 4096, [&](long bcl) {
    const int bc = static_cast<int>(bcl), b = bc / ci, c = bc % ci;
    float* dst = u + static_cast<std::size_t>(bc) * kCB;
    for (int half = 0; half < 2; ++half) {
      const int o0 = b * kCB + 4 * half;
      const __m128 live = _mm_castsi128_ps(_mm_cmpgt_epi32(_mm_set1_epi32(co - o0), _mm_setr_epi32(0, 1, 2, 3)));
      const float* base = transpose_flip ? w + (static_cast<std::size_t>(c) * co + o0) * 9 + 8
                                         : w + (static_cast<std::size_t>(o0) * ci + c) * 9;
      __m256d k[9];
      for (int t = 0; t < 9; ++t) {
        const __m128i idx = _mm_add_epi32(idx0, _mm_set1_epi32(transpose_flip ? -t : t));
        k[t] = _mm256_cvtps_pd(_mm_mask_i32gather_ps(_mm_setzero_ps(), base, idx, live, 4));
      }
      __m256d gk[3][6];  // G' k: [kw][a]
      for (int kw = 0; kw < 3; ++kw) g6(k[kw], k[3 + kw], k[6 + kw], gk[kw]);
      for (int a = 0; a < 6; ++a) {
        __m256d r[6];
        g6(gk[0][a], gk[1][a], gk[2][a], r);
        for (int bb = 0; bb < 6; ++bb)
          _mm_store_ps(dst + (a * 6 + bb) * per_e + 4 * half,
                       _mm256_cvtpd_ps(_mm256_mul_pd(_mm256_set1_pd(kGScale.s[a][bb]), r[bb])));
      }
    }
  });
}

// A^T applied to 6 values: the output transform's 1-D step.
inline void at6(const __m256 m[6], __m256 y[4]) {
  const __m256 s12 = _mm256_add_ps(m[1], m[2]), d12 = _mm256_sub_ps(m[1], m[2]);
  const __m256 s34 = _mm256_add_ps(m[3], m[4]), d34 = _mm256_sub_ps(m[3], m[4]);
  y[0] = _mm256_add_ps(_mm256_add_ps(m[0], s12), s34);
  y[1] = _mm256_fmadd_ps(_mm256_set1_ps(2.f), d34, d12);
  y[2] = _mm256_fmadd_ps(_mm256_set1_ps(4.f), s34, s12);
  y[3] = _mm256_add_ps(_mm256_fmadd_ps(_mm256_set1_ps(8.f), d34, d12), m[5]);
}

// V[e][c][8 lanes] for 8 tiles of channel c: tile row ty, first tile tx.
inline void input_tile(float* v, std::size_t e_stride, const float* plane, const Geom& g, int ty, int tx) {
  __m256 t[6][6];
  for (int i = 0; i < 6; ++i) {
    const float* row = plane + static_cast<std::size_t>(4 * ty + i) * 4 * g.len + tx;
    __m256 x[6];
    for (int k = 0; k < 6; ++k) x[k] = _mm256_loadu_ps(row + (k & 3) * g.len + (k >> 2));
    bt6(x, t[i]);
  }
  bt_columns_store(v, e_stride, t);
}

// Prefetches the 24 (row, phase) lines that the input tiles of a block (tiles tx .. tx + tb, tile
// row ty) read from one channel's by-phase plane: a block reads 2-3 cache lines of each, too short
// a stream for the hardware prefetcher, and the channels' planes lie far apart.
inline void prefetch_tile_lines(const float* plane, const Geom& g, int ty, int tx) {
  for (int i = 0; i < 6; ++i)
    for (int r = 0; r < 4; ++r) {
      const float* line = plane + (static_cast<std::size_t>(4 * ty + i) * 4 + r) * g.len + tx;
      for (int f = 0; f <= g.tb; f += 16) _mm_prefetch(reinterpret_cast<const char*>(line + f), _MM_HINT_T0);
    }
}

// M rows row0 .. row0 + R - 1 x 8 Q tiles = U^T V for one transform element: U rows of the
// packed [blocks][ci][kCB] layout (row r: block r / kCB, lane r % kCB), V [ci][v_stride] from
// the group's first tile. R Q accumulators stay in registers (12 of the 16 at most): enough
// independent chains to keep both FMA pipes busy.
// (The accumulators are named variables, not an array: GCC 12 keeps an array of them in memory
// and stores every accumulator on each pass of the loop.)
template <int R, int Q>
inline void gemm_rows(float* m, int m_stride, const float* v, int v_stride, const float* u, int row0, int ci) {
  static_assert(R >= 1 && R <= 6 && Q >= 1 && Q <= 3, "up to 6 rows x 3 vectors");
  std::size_t off[6] = {};
  for (int r = 0; r < R; ++r) off[r] = static_cast<std::size_t>((row0 + r) / kCB) * ci * kCB + (row0 + r) % kCB;
  const __m256 z = _mm256_setzero_ps();
  __m256 a00 = z, a01 = z, a02 = z, a10 = z, a11 = z, a12 = z, a20 = z, a21 = z, a22 = z;
  __m256 a30 = z, a31 = z, a32 = z, a40 = z, a41 = z, a42 = z, a50 = z, a51 = z, a52 = z;
  for (int c = 0; c < ci; ++c) {
    const float* vc = v + static_cast<std::size_t>(c) * v_stride;
    const __m256 x0 = _mm256_load_ps(vc);
    const __m256 x1 = Q > 1 ? _mm256_load_ps(vc + 8) : z;
    const __m256 x2 = Q > 2 ? _mm256_load_ps(vc + 16) : z;
    const float* uc = u + static_cast<std::size_t>(c) * kCB;
#define LIDARSIM_GEMM_ROW(r)                                             \
  if constexpr (R > r) {                                                 \
    const __m256 wv = _mm256_broadcast_ss(uc + off[r]);                  \
    a##r##0 = _mm256_fmadd_ps(wv, x0, a##r##0);                          \
    if constexpr (Q > 1) a##r##1 = _mm256_fmadd_ps(wv, x1, a##r##1);     \
    if constexpr (Q > 2) a##r##2 = _mm256_fmadd_ps(wv, x2, a##r##2);     \
  }
    LIDARSIM_GEMM_ROW(0) LIDARSIM_GEMM_ROW(1) LIDARSIM_GEMM_ROW(2) LIDARSIM_GEMM_ROW(3) LIDARSIM_GEMM_ROW(4)
    LIDARSIM_GEMM_ROW(5)
#undef LIDARSIM_GEMM_ROW
  }
  const __m256 acc[6][3] = {{a00, a01, a02}, {a10, a11, a12}, {a20, a21, a22},
                            {a30, a31, a32}, {a40, a41, a42}, {a50, a51, a52}};
  for (int r = 0; r < R; ++r)
    for (int q = 0; q < Q; ++q)
      _mm256_store_ps(m + static_cast<std::size_t>(row0 + r) * m_stride + 8 * q, acc[r][q]);
}

// M rows [0, rows) x tb tiles for one transform element, in row groups of R and tile groups of
// 8 Q (R Q = 12), the last row group narrower.
template <int R, int Q>
inline void gemm_element(float* m, int tb, const float* v, const float* u, int rows, int ci) {
  for (int r0 = 0; r0 < rows; r0 += R) {
    const int nr = std::min(R, rows - r0);
    for (int t0 = 0; t0 < tb; t0 += 8 * Q) {
      float* mt = m + t0;
      const float* vt = v + t0;
      if (nr == R) {
        gemm_rows<R, Q>(mt, tb, vt, tb, u, r0, ci);
        continue;
      }
      switch (nr) {
        case 1: gemm_rows<1, Q>(mt, tb, vt, tb, u, r0, ci); break;
        case 2: gemm_rows<2, Q>(mt, tb, vt, tb, u, r0, ci); break;
        case 3: gemm_rows<3, Q>(mt, tb, vt, tb, u, r0, ci); break;
        case 4: gemm_rows<4, Q>(mt, tb, vt, tb, u, r0, ci); break;
        default: gemm_rows<5, Q>(mt, tb, vt, tb, u, r0, ci); break;
      }
    }
  }
}

// Writes y[0..3] (output column j of 8 tiles) as 32 consecutive pixels, the first `valid` of them.
inline void store_interleaved(float* dst, const __m256 y[4], int valid) {
  const __m256 a = _mm256_unpacklo_ps(y[0], y[1]), b = _mm256_unpackhi_ps(y[0], y[1]);
  const __m256 c = _mm256_unpacklo_ps(y[2], y[3]), d = _mm256_unpackhi_ps(y[2], y[3]);
  // Per 128-bit half: t0 = tiles 0 | 4, t1 = 1 | 5, t2 = 2 | 6, t3 = 3 | 7, columns j = 0..3 each.
  const __m256 t0 = _mm256_castpd_ps(_mm256_unpacklo_pd(_mm256_castps_pd(a), _mm256_castps_pd(c)));
  const __m256 t1 = _mm256_castpd_ps(_mm256_unpackhi_pd(_mm256_castps_pd(a), _mm256_castps_pd(c)));
  const __m256 t2 = _mm256_castpd_ps(_mm256_unpacklo_pd(_mm256_castps_pd(b), _mm256_castps_pd(d)));
  const __m256 t3 = _mm256_castpd_ps(_mm256_unpackhi_pd(_mm256_castps_pd(b), _mm256_castps_pd(d)));
  const __m256 o[4] = {_mm256_permute2f128_ps(t0, t1, 0x20), _mm256_permute2f128_ps(t2, t3, 0x20),
                       _mm256_permute2f128_ps(t0, t1, 0x31), _mm256_permute2f128_ps(t2, t3, 0x31)};
  for (int q = 0; q < 4 && valid > 0; ++q, valid -= 8) {
    if (valid >= 8)
      _mm256_storeu_ps(dst + 8 * q, o[q]);
    else
      _mm256_maskstore_ps(dst + 8 * q, first_lanes(valid), o[q]);
  }
}

// Output tiles of one channel for 8 tiles: A^T M A, bias, ReLU, written to out.
inline void output_tile(float* out_plane, const float* m, std::size_t e_stride, const Geom& g, int ty, int tx,
                        float bias, bool relu) {
  const int x0 = 4 * tx, valid = std::min(32, g.w - x0);
  if (valid <= 0) return;
  __m256 t[6][4];
  for (int a = 0; a < 6; ++a) {
    __m256 row[6];
    for (int bb = 0; bb < 6; ++bb) row[bb] = _mm256_load_ps(m + (a * 6 + bb) * e_stride);
    at6(row, t[a]);
  }
  const __m256 bv = _mm256_set1_ps(bias), zero = _mm256_setzero_ps();
  __m256 y[4][4];
  for (int j = 0; j < 4; ++j) {
    __m256 col[6], r[4];
    for (int a = 0; a < 6; ++a) col[a] = t[a][j];
    at6(col, r);
    for (int i = 0; i < 4; ++i) y[i][j] = relu ? _mm256_max_ps(_mm256_add_ps(r[i], bv), zero) : _mm256_add_ps(r[i], bv);
  }
  for (int i = 0; i < 4; ++i) {
    const int yrow = 4 * ty + i;
    if (yrow >= g.h) break;
    store_interleaved(out_plane + static_cast<std::size_t>(yrow) * g.w + x0, y[i], valid);
  }
}

// Tasks: (image, tile row, block of tb tiles), times output-channel parts when there are few.
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
  const bool q3 = g.tb % 24 == 0;  // 48 tiles: groups of 24 tiles x 4 rows, else 16 tiles x 6 rows
  parallel_shared(tasks, flops > 2e6, [&](int tid, int nt, Shares& shares) {
    const std::size_t v_e = static_cast<std::size_t>(ci) * g.tb + 16;  // one cache line past each slice
    float* v = tl_v.get(36 * v_e);
    shares.run(tid, nt, [&](long tl) {
      const int task = static_cast<int>(tl), part = task % parts, tt = task / parts;
      const int img = tt / (g.th * g.blocks), ty = (tt / g.blocks) % g.th, blk = tt % g.blocks;
      const int b0 = co_blocks * part / parts, b1 = co_blocks * (part + 1) / parts;
      const std::size_t m_e = static_cast<std::size_t>(b1 - b0) * kCB * g.tb + 16;
      float* m = tl_m.get(36 * m_e);
      for (int c = 0; c < ci; ++c) {
        const float* plane = phases + (static_cast<std::size_t>(img) * ci + c) * g.plane;
        if (c + 1 < ci) prefetch_tile_lines(plane + g.plane, g, ty, blk * g.tb);
        for (int t = 0; t < g.tb; t += 8)
          input_tile(v + static_cast<std::size_t>(c) * g.tb + t, v_e, plane, g, ty, blk * g.tb + t);
      }
      // Rows past the last output channel (zero weights) are left out.
      const int rows = std::min(co, b1 * kCB) - b0 * kCB;
      for (int e = 0; e < 36; ++e) {
        const float* ue = u + e * u_e + static_cast<std::size_t>(b0) * ci * kCB;
        if (q3)
          gemm_element<4, 3>(m + e * m_e, g.tb, v + e * v_e, ue, rows, ci);
        else
          gemm_element<6, 2>(m + e * m_e, g.tb, v + e * v_e, ue, rows, ci);
      }
      for (int o = b0 * kCB; o < std::min(co, b1 * kCB); ++o) {
        float* op = plane_of(out, img, o, hw);
        const float* mo = m + static_cast<std::size_t>(o - b0 * kCB) * g.tb;
        for (int t = 0; t < g.tb; t += 8)
          output_tile(op, mo + t, m_e, g, ty, blk * g.tb + t, bias ? bias[o] : 0.f, relu);
      }
    });
  });
}

// The 32 floats at row (tiles t .. t + 7, phases 0..3 each) split by phase: phase r of the 8
// tiles to line + r len. An 8 x 4 transpose.
inline void store_phases(float* line, int len, const float* row) {
  const __m256 in0 = _mm256_loadu_ps(row), in1 = _mm256_loadu_ps(row + 8);
  const __m256 in2 = _mm256_loadu_ps(row + 16), in3 = _mm256_loadu_ps(row + 24);
  // Tiles k | k + 4 in the two halves.
  const __m256 a = _mm256_permute2f128_ps(in0, in2, 0x20), b = _mm256_permute2f128_ps(in0, in2, 0x31);
  const __m256 c = _mm256_permute2f128_ps(in1, in3, 0x20), d = _mm256_permute2f128_ps(in1, in3, 0x31);
  const __m256d u0 = _mm256_castps_pd(_mm256_unpacklo_ps(a, b)), u1 = _mm256_castps_pd(_mm256_unpackhi_ps(a, b));
  const __m256d u2 = _mm256_castps_pd(_mm256_unpacklo_ps(c, d)), u3 = _mm256_castps_pd(_mm256_unpackhi_ps(c, d));
  _mm256_storeu_ps(line, _mm256_castpd_ps(_mm256_unpacklo_pd(u0, u2)));
  _mm256_storeu_ps(line + len, _mm256_castpd_ps(_mm256_unpackhi_pd(u0, u2)));
  _mm256_storeu_ps(line + 2 * len, _mm256_castpd_ps(_mm256_unpacklo_pd(u1, u3)));
  _mm256_storeu_ps(line + 3 * len, _mm256_castpd_ps(_mm256_unpackhi_pd(u1, u3)));
}

// One plane into the by-phase layout; returns the sum of the (masked) values: 8 running sums
// over each row's floats in order, rows from y = 0 down, then added lane by lane.
float plane_to_phases(float* d, const float* src, const float* m, const Geom& g, bool want_sum) {
  const std::size_t line = static_cast<std::size_t>(4) * g.len;
  std::fill(d, d + line, 0.f);  // padded row 0
  std::fill(d + static_cast<std::size_t>(g.h + 1) * line, d + g.plane, 0.f);
  // row[1 + x] = pixel x; row[0] and everything past the last pixel stay zero.
  if (tl_row.size() < line + 8) tl_row.resize(line + 8);
  float* row = tl_row.data();
  std::fill(row, row + line, 0.f);
  __m256 acc = _mm256_setzero_ps();
  const int sum_floats = (g.w + 1 + 7) / 8 * 8;
  for (int y = 0; y < g.h; ++y) {
    const float* s = src + static_cast<std::size_t>(y) * g.w;
    if (m) {
      const float* mr = m + static_cast<std::size_t>(y) * g.w;
      for (int x = 0; x < g.w; ++x) row[1 + x] = mr[x] > 0.f ? s[x] : 0.f;
    } else {
      std::copy(s, s + g.w, row + 1);
    }
    if (want_sum)
      for (int x = 0; x < sum_floats; x += 8) acc = _mm256_add_ps(acc, _mm256_loadu_ps(row + x));
    float* dl = d + static_cast<std::size_t>(y + 1) * line;
    for (int t = 0; t < g.len; t += 8) store_phases(dl + t, g.len, row + 4 * t);
  }
  alignas(32) float lanes[8];
  _mm256_store_ps(lanes, acc);
  float total = 0.f;
  for (float l : lanes) total += l;
  return total;
}

}  // namespace

namespace wino {

void to_phases(float* dst, const PlaneSet& in, const float* mask, int n, const Geom& g, float* sums) {
  const int ci = in.ca + in.cb;
  const std::size_t hw = static_cast<std::size_t>(g.h) * g.w;
  const bool par = static_cast<std::size_t>(n) * ci * hw > (1u << 15);
  parallel_for(n * ci, par, [&](long p) {
    const int img = static_cast<int>(p / ci), ch = static_cast<int>(p % ci);
    const float* m = mask ? mask + static_cast<std::size_t>(p) * hw : nullptr;
    const float total = plane_to_phases(dst + static_cast<std::size_t>(p) * g.plane, plane_of(in, img, ch, hw), m, g,
                                        sums != nullptr);
    if (sums) sums[p] = total;
  });
}

void conv_from_phases(const OutPlaneSet& out, const float* phases, int ci, int n, const Geom& g, const float* weight,
                      bool transpose_flip, const float* bias, bool relu) {
  const int co = out.ca + out.cb;
  float* u = tl_u.get(36 * u_stride(co, ci));
  transform_weights(u, weight, co, ci, transpose_flip);
  run(out, phases, n, ci, g, u, bias, relu);
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

}  // namespace lidarsim::nn::detail::avx2

#endif
