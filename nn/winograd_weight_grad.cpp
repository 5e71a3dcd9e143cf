// See nn/winograd.h: the weight gradient through the transposed algorithm, and the backward pass
// that shares its by-phase copy of the output gradient with the input gradient. GCC 12's AVX-512
// headers trip -W(maybe-)uninitialized (as in conv3x3.cpp).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/winograd.h"

#include <algorithm>
#include <cstddef>

#include "nn/avx512_util.h"
#include "nn/parallel.h"
#include "nn/winograd_tiles.h"

#if !LIDARSIM_AVX512_KERNELS
namespace lidarsim::nn::detail::avx512 {
void winograd_weight_grad(float*, const PlaneSet&, const float*, const float*, int, int, int, int, float*) {}
void winograd_backward(const OutPlaneSet&, float*, const PlaneSet&, const float*, const float*, int, int, int,
                       const float*, int, float*) {}
}  // namespace lidarsim::nn::detail::avx512
#else

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512 {

using namespace wino;

namespace {

// Scratch of one call, per calling thread (as in winograd.cpp); workers get the pointers.
thread_local Buf tl_phase_grad, tl_du;
thread_local Buf tl_rows;

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

// How the tiles are cut into chunks, slots and output-channel parts: a function of the shapes
// only (never of the thread count), so the sums run in the same order on any machine.
struct ChunkPlan {
  int ci, co, cgs, ci16, co8, ob;
  int span;      // tiles per tile row, whole 16-tile vectors
  int chunk;     // tiles per chunk
  int per_row;   // chunks per tile row
  long chunks;   // chunks in all images
  std::size_t du_floats;  // one slot's partial dU
  int slots, parts;
  bool par;
  int cols;            // interleaved input columns per chunk
  std::size_t v_e;     // floats per transform element of V
  ChunkPlan(const PlaneSet& in, int co_, int n, const Geom& g) : ci(in.ca + in.cb), co(co_) {
    cgs = (ci + 15) / 16, ci16 = 16 * cgs;
    co8 = (co + kCB - 1) / kCB * kCB, ob = co8 / kCB;
    span = (g.tw + 15) / 16 * 16;
    const int tile_cap = std::max(16, kChunkFloats / (36 * (ci16 + co8)) / 16 * 16);
    chunk = std::min({span, tile_cap, 128});
    per_row = (span + chunk - 1) / chunk;
    chunks = static_cast<long>(n) * g.th * per_row;
    // The slots are contiguous runs of chunks, each summed in order into its own partial dU.
    // Output-channel parts (each repeating the cheap input transform) give the deep layers, with
    // few tiles, more tasks.
    du_floats = static_cast<std::size_t>(36) * co8 * ci16;
    slots = static_cast<int>(
        std::max<long>(1, std::min<long>({chunks, kMaxSlots, static_cast<long>(kSlotFloats / du_floats)})));
    const int want = 4 * team_threads();
    parts = slots >= want ? 1 : std::min(ob, (want + slots - 1) / slots);
    const double flops = 2.0 * 36 * static_cast<double>(chunks) * chunk * ci * co;
    par = flops > 2e6;
    cols = (4 * chunk + 2 + 15) / 16 * 16;
    v_e = static_cast<std::size_t>(chunk) * ci16 + 16;
  }
};

// One task: slot s's chunks, for the output channels of part p, summed in chunk order into the
// slot's partial dU (du + s du_floats). rows and v are this thread's scratch.
void slot_part_du(const ChunkPlan& pl, long task, const PlaneSet& in, const float* pg, const Geom& g, float* du,
                  float* rows, float* v) {
  const int ci16 = pl.ci16, co8 = pl.co8, ob = pl.ob, co = pl.co, chunk = pl.chunk, cols = pl.cols;
  const int parts = pl.parts, slots = pl.slots, per_row = pl.per_row;
  const std::size_t v_e = pl.v_e;
  const int s = static_cast<int>(task / parts), p = static_cast<int>(task % parts);
  const int o0 = kCB * (ob * p / parts), o1 = kCB * (ob * (p + 1) / parts), orows = o1 - o0;
  const std::size_t m_e = static_cast<std::size_t>(orows) * chunk + 16;
  float* m = tl_m.get(36 * m_e);
  float* dus = du + s * pl.du_floats;
  for (int e = 0; e < 36; ++e) {
    std::fill(dus + (static_cast<std::size_t>(e) * co8 + o0) * ci16, dus + (static_cast<std::size_t>(e) * co8 + o1) * ci16,
              0.f);
    for (int o = std::max(co, o0); o < o1; ++o)  // the block's rows past the last channel
      std::fill(m + e * m_e + static_cast<std::size_t>(o - o0) * chunk,
                m + e * m_e + static_cast<std::size_t>(o - o0 + 1) * chunk, 0.f);
  }
  const long c_begin = pl.chunks * s / slots, c_end = pl.chunks * (s + 1) / slots;
  for (long c = c_begin; c < c_end; ++c) {
    const int img = static_cast<int>(c / (static_cast<long>(g.th) * per_row));
    const int ty = static_cast<int>(c / per_row % g.th), t0 = static_cast<int>(c % per_row) * chunk;
    const int tiles = std::min(chunk, pl.span - t0);
    interleave_rows(rows, cols, in, img, g, ty, t0);
    for (int t = 0; t < tiles; ++t)
      for (int cg = 0; cg < pl.cgs; ++cg)
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
}

// dU = the slots' partial sums, added in slot order (into slot 0).
void add_slots_in_order(float* du, const ChunkPlan& pl) {
  if (pl.slots <= 1) return;
  const std::size_t du_floats = pl.du_floats;
  parallel_for((du_floats + 1023) / 1024, pl.par, [&](long blk) {
    const std::size_t i0 = static_cast<std::size_t>(blk) * 1024, i1 = std::min(du_floats, i0 + 1024);
    for (int s = 1; s < pl.slots; ++s) {
      const float* src = du + s * du_floats;
      for (std::size_t i = i0; i < i1; ++i) du[i] += src[i];
    }
  });
}

// d_weight += G^T dU G per kernel, in double: 8 input channels in the lanes of a double vector
// (contiguous in dU), each lane doing the scalar sums in their order (multiply, then add; no
// FMA), so the result is the same bits as one kernel at a time.
void add_weight_grad_from_du(float* d_weight, const float* du, const ChunkPlan& pl) {
  static constexpr double G[6][3] = {{1.0 / 4, 0, 0},
                                     {-1.0 / 6, -1.0 / 6, -1.0 / 6},
                                     {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                     {1.0 / 24, 1.0 / 12, 1.0 / 6},
                                     {1.0 / 24, -1.0 / 12, 1.0 / 6},
                                     {0, 0, 1}};
  const int ci = pl.ci, ci16 = pl.ci16;
  const std::size_t du_e = static_cast<std::size_t>(pl.co8) * ci16;
  const int c_blocks = (ci + 7) / 8;
  parallel_for(pl.co * c_blocks, pl.par, [&](long ocl) {
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

void weight_grad_streaming(float* d_weight, const PlaneSet& in, const float* pg, int co, int n, const Geom& g) {
  const ChunkPlan pl(in, co, n, g);
  float* du = tl_du.get(pl.slots * pl.du_floats);
  parallel_shared(pl.slots * pl.parts, pl.par, [&](int tid, int nt, Shares& shares) {
    float* rows = tl_rows.get(static_cast<std::size_t>(pl.cgs) * 6 * pl.cols * 16);
    float* v = tl_v.get(36 * pl.v_e);
    shares.run(tid, nt, [&](long task) { slot_part_du(pl, task, in, pg, g, du, rows, v); });
  });
  add_slots_in_order(du, pl);
  add_weight_grad_from_du(d_weight, du, pl);
}


// The weight gradient from the input and a by-phase copy of the masked output gradient; returns
// the latter, which the input gradient reads too.
const float* weight_grad_via_phases(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n,
                                    int co, const Geom& g, float* sums) {
  float* pg = tl_phase_grad.get(static_cast<std::size_t>(n) * co * g.plane);
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

}  // namespace lidarsim::nn::detail::avx512
#include "nn/isa_avx512_end.h"

#endif
