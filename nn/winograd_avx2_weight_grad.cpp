// The AVX2 port of the Winograd weight gradient (nn/winograd.h, namespace avx2): the structure of
// nn/winograd_weight_grad.cpp with 8-lane vectors, 8 input channels per vector instead of 16. The
// tiles stream in chunks (one image, one tile row, up to 128 tiles); each chunk's input tiles are
// transformed with 8 channels per vector, its output-gradient tiles with 8 tiles per vector, and
// per transform element a GEMM over the chunk's tiles keeps a 4 x 24 result block in registers.
// Chunks are summed in up to 8 slots fixed by the shapes, the slots added in order: the result
// does not depend on the thread count.
#include <algorithm>
#include <cstddef>

#include "nn/parallel.h"
#include "nn/winograd_avx2.h"

#if !LIDARSIM_AVX2_KERNELS
namespace lidarsim::nn::detail::avx2 {
void winograd_weight_grad(float*, const PlaneSet&, const float*, const float*, int, int, int, int, float*) {}
void winograd_backward(const OutPlaneSet&, float*, const PlaneSet&, const float*, const float*, int, int, int,
                       const float*, int, float*) {}
}  // namespace lidarsim::nn::detail::avx2
#else

namespace lidarsim::nn::detail::avx2 {

using namespace wino;

namespace {

// Scratch of one call, per calling thread (as in winograd_avx2.cpp); workers get the pointers.
thread_local Buf tl_phase_grad, tl_du, tl_rows;

// A applied to 4 values (the transpose of the output transform's A^T): the output gradient's 1-D step.
inline void a4(const __m256 y[4], __m256 m[6]) {
  const __m256 s02 = _mm256_add_ps(y[0], y[2]), s13 = _mm256_add_ps(y[1], y[3]);
  const __m256 t02 = _mm256_fmadd_ps(_mm256_set1_ps(4.f), y[2], y[0]);
  const __m256 t13 = _mm256_fmadd_ps(_mm256_set1_ps(8.f), y[3], _mm256_mul_ps(_mm256_set1_ps(2.f), y[1]));
  m[0] = y[0];
  m[1] = _mm256_add_ps(s02, s13);
  m[2] = _mm256_sub_ps(s02, s13);
  m[3] = _mm256_add_ps(t02, t13);
  m[4] = _mm256_sub_ps(t02, t13);
  m[5] = y[3];
}

// dM[e][8 lanes] = (A dY A^T)[e] for 8 tiles of one output-gradient channel, read from its by-phase
// layout: output pixel (4 ty + i, 4 tx + j) is padded row 4 ty + 1 + i, phase (j + 1) & 3 of tile
// tx + (j + 1) / 4.
inline void grad_tile(float* m, std::size_t e_stride, const float* plane, const Geom& g, int ty, int tx) {
  __m256 t[4][6];
  for (int i = 0; i < 4; ++i) {
    const float* row = plane + static_cast<std::size_t>(4 * ty + 1 + i) * 4 * g.len + tx;
    __m256 y[4];
    for (int j = 0; j < 4; ++j) y[j] = _mm256_loadu_ps(row + ((j + 1) & 3) * g.len + ((j + 1) >> 2));
    a4(y, t[i]);
  }
  for (int b = 0; b < 6; ++b) {
    __m256 col[4], r[6];
    for (int i = 0; i < 4; ++i) col[i] = t[i][b];
    a4(col, r);
    for (int a = 0; a < 6; ++a) _mm256_store_ps(m + (a * 6 + b) * e_stride, r[a]);
  }
}

// col[x] lane k = r[k] lane x: the 8 x 8 transpose.
inline void transpose8(const __m256 r[8], __m256 col[8]) {
  __m256 t[8], s[8];
  for (int i = 0; i < 4; ++i) {
    t[2 * i] = _mm256_unpacklo_ps(r[2 * i], r[2 * i + 1]);
    t[2 * i + 1] = _mm256_unpackhi_ps(r[2 * i], r[2 * i + 1]);
  }
  // s[4 h + j]: rows 4 h .. 4 h + 3 of columns j | j + 4.
  for (int h = 0; h < 2; ++h) {
    s[4 * h] = _mm256_shuffle_ps(t[4 * h], t[4 * h + 2], 0x44);
    s[4 * h + 1] = _mm256_shuffle_ps(t[4 * h], t[4 * h + 2], 0xEE);
    s[4 * h + 2] = _mm256_shuffle_ps(t[4 * h + 1], t[4 * h + 3], 0x44);
    s[4 * h + 3] = _mm256_shuffle_ps(t[4 * h + 1], t[4 * h + 3], 0xEE);
  }
  for (int j = 0; j < 4; ++j) {
    col[j] = _mm256_permute2f128_ps(s[j], s[4 + j], 0x20);
    col[4 + j] = _mm256_permute2f128_ps(s[j], s[4 + j], 0x31);
  }
}

// rows [cgs][6][cols][8]: input rows 4 ty - 1 .. 4 ty + 4, columns 4 t0 - 1 + j (j < cols, a
// multiple of 8), channel 8 group + lane; zeros outside the image and past the last channel.
void interleave_rows(float* rows, int cols, const PlaneSet& in, int img, const Geom& g, int ty, int t0) {
  const int ci = in.ca + in.cb, cgs = (ci + 7) / 8;
  const std::size_t hw = static_cast<std::size_t>(g.h) * g.w;
  const __m256 zero = _mm256_setzero_ps();
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  for (int cg = 0; cg < cgs; ++cg) {
    const float* planes[8];
    for (int l = 0; l < 8; ++l) planes[l] = 8 * cg + l < ci ? plane_of(in, img, 8 * cg + l, hw) : nullptr;
    for (int i = 0; i < 6; ++i) {
      float* dst = rows + (static_cast<std::size_t>(cg) * 6 + i) * cols * 8;
      const int y = 4 * ty - 1 + i;
      if (y < 0 || y >= g.h) {
        std::fill(dst, dst + static_cast<std::size_t>(cols) * 8, 0.f);
        continue;
      }
      for (int j0 = 0; j0 < cols; j0 += 8) {
        const int x0 = 4 * t0 - 1 + j0;
        const bool inside = x0 >= 0 && x0 + 8 <= g.w;
        // Lanes whose pixel x0 + lane lies in [0, w).
        const __m256i k = _mm256_and_si256(_mm256_cmpgt_epi32(_mm256_set1_epi32(g.w - x0), lane),
                                           _mm256_cmpgt_epi32(lane, _mm256_set1_epi32(-x0 - 1)));
        const bool any = x0 + 8 > 0 && x0 < g.w;
        __m256 r[8], col[8];
        for (int l = 0; l < 8; ++l) {
          const float* p = planes[l] ? planes[l] + static_cast<std::size_t>(y) * g.w + x0 : nullptr;
          r[l] = !p || !any ? zero : inside ? _mm256_loadu_ps(p) : _mm256_maskload_ps(p, k);
        }
        transpose8(r, col);
        for (int p = 0; p < 8; ++p) _mm256_store_ps(dst + static_cast<std::size_t>(j0 + p) * 8, col[p]);
      }
    }
  }
}

// V[e][8 channels] of chunk tile t from one channel group's interleaved rows (as input_tile of
// winograd_avx2.cpp, with channels in the lanes instead of tiles).
inline void input_tile_interleaved(float* v, std::size_t e_stride, const float* rows, int cols, int t) {
  __m256 tr[6][6];
  for (int i = 0; i < 6; ++i) {
    const float* row = rows + (static_cast<std::size_t>(i) * cols + 4 * t) * 8;
    __m256 x[6];
    for (int k = 0; k < 6; ++k) x[k] = _mm256_load_ps(row + 8 * k);
    bt6(x, tr[i]);
  }
  bt_columns_store(v, e_stride, tr);
}

// du[4 rows][8 CV channels] += sum over tiles t < tiles of dm[row][t] v[t][channels]: the
// 4 x CV accumulators stay in registers while the tiles stream past (named variables: GCC 12
// stores an array of them to memory on every pass of the loop).
template <int CV>
inline void du_block(float* du, std::size_t du_row, const float* dm, std::size_t dm_row, const float* v,
                     std::size_t v_row, int tiles) {
  static_assert(CV >= 1 && CV <= 3, "up to 3 vectors of channels");
  const __m256 z = _mm256_setzero_ps();
  auto ld = [&](int b, int q) { return q < CV ? _mm256_load_ps(du + b * du_row + 8 * q) : z; };
  __m256 a00 = ld(0, 0), a01 = ld(0, 1), a02 = ld(0, 2), a10 = ld(1, 0), a11 = ld(1, 1), a12 = ld(1, 2);
  __m256 a20 = ld(2, 0), a21 = ld(2, 1), a22 = ld(2, 2), a30 = ld(3, 0), a31 = ld(3, 1), a32 = ld(3, 2);
  for (int t = 0; t < tiles; ++t) {
    const float* vt = v + t * v_row;
    const __m256 x0 = _mm256_load_ps(vt);
    const __m256 x1 = CV > 1 ? _mm256_load_ps(vt + 8) : z;
    const __m256 x2 = CV > 2 ? _mm256_load_ps(vt + 16) : z;
#define LIDARSIM_DU_ROW(b)                                                \
  {                                                                       \
    const __m256 gv = _mm256_broadcast_ss(dm + b * dm_row + t);           \
    a##b##0 = _mm256_fmadd_ps(gv, x0, a##b##0);                           \
    if constexpr (CV > 1) a##b##1 = _mm256_fmadd_ps(gv, x1, a##b##1);     \
    if constexpr (CV > 2) a##b##2 = _mm256_fmadd_ps(gv, x2, a##b##2);     \
  }
    LIDARSIM_DU_ROW(0) LIDARSIM_DU_ROW(1) LIDARSIM_DU_ROW(2) LIDARSIM_DU_ROW(3)
#undef LIDARSIM_DU_ROW
  }
  const __m256 acc[4][3] = {{a00, a01, a02}, {a10, a11, a12}, {a20, a21, a22}, {a30, a31, a32}};
  for (int b = 0; b < 4; ++b)
    for (int q = 0; q < CV; ++q) _mm256_store_ps(du + b * du_row + 8 * q, acc[b][q]);
}

// A chunk's transformed tiles (V and dM) take up to 1.5 MB, as in the AVX-512 kernel.
constexpr int kChunkFloats = 393216;
constexpr int kMaxSlots = 8;                                // partial sums of the tiles, added in order
constexpr std::size_t kSlotFloats = std::size_t{1} << 22;   // all slots' partial sums: at most 16 MB

// How the tiles are cut into chunks, slots and output-channel parts: a function of the shapes
// only (never of the thread count), so the sums run in the same order on any machine.
struct ChunkPlan {
  int ci, co, cgs, ci8, co8, ob;
  int span;      // tiles per tile row, whole 16-tile groups
  int chunk;     // tiles per chunk
  int per_row;   // chunks per tile row
  long chunks;   // chunks in all images
  std::size_t du_floats;  // one slot's partial dU [36][co8][ci8]
  int slots, parts;
  bool par;
  int cols;         // interleaved input columns per chunk
  std::size_t v_e;  // floats per transform element of V
  ChunkPlan(const PlaneSet& in, int co_, int n, const Geom& g) : ci(in.ca + in.cb), co(co_) {
    cgs = (ci + 7) / 8, ci8 = 8 * cgs;
    co8 = (co + kCB - 1) / kCB * kCB, ob = co8 / kCB;
    span = (g.tw + 15) / 16 * 16;
    const int tile_cap = std::max(16, kChunkFloats / (36 * (ci8 + co8)) / 16 * 16);
    chunk = std::min({span, tile_cap, 128});
    per_row = (span + chunk - 1) / chunk;
    chunks = static_cast<long>(n) * g.th * per_row;
    du_floats = static_cast<std::size_t>(36) * co8 * ci8;
    slots = static_cast<int>(
        std::max<long>(1, std::min<long>({chunks, kMaxSlots, static_cast<long>(kSlotFloats / du_floats)})));
    // Output-channel parts (each repeating the cheap input transform) give the deep layers, with
    // few tiles, more tasks; they split the rows of dU, not the order of any sum.
    const int want = 4 * team_threads();
    parts = slots >= want ? 1 : std::min(ob, (want + slots - 1) / slots);
    par = 2.0 * 36 * static_cast<double>(chunks) * chunk * ci * co > 2e6;
    cols = (4 * chunk + 2 + 7) / 8 * 8;
    v_e = static_cast<std::size_t>(chunk) * ci8 + 16;
  }
};

// dU rows [o, o + 4) of one transform element += dm x V over a chunk's tiles, 24 channels at a time.
inline void du_rows4(float* d, const float* dm, const float* ve, const ChunkPlan& pl, int tiles) {
  int c8 = 0;
  for (; c8 + 24 <= pl.ci8; c8 += 24) du_block<3>(d + c8, pl.ci8, dm, pl.chunk, ve + c8, pl.ci8, tiles);
  if (pl.ci8 - c8 == 16) du_block<2>(d + c8, pl.ci8, dm, pl.chunk, ve + c8, pl.ci8, tiles);
  if (pl.ci8 - c8 == 8) du_block<1>(d + c8, pl.ci8, dm, pl.chunk, ve + c8, pl.ci8, tiles);
}

// One task: slot s's chunks, for the output channels of part p, summed in chunk order into the
// slot's partial dU (du + s du_floats). rows and v are this thread's scratch.
void slot_part_du(const ChunkPlan& pl, long task, const PlaneSet& in, const float* pg, const Geom& g, float* du,
                  float* rows, float* v) {
  const int ci8 = pl.ci8, co8 = pl.co8, ob = pl.ob, co = pl.co, chunk = pl.chunk, cols = pl.cols;
  const int s = static_cast<int>(task / pl.parts), p = static_cast<int>(task % pl.parts);
  const int o0 = kCB * (ob * p / pl.parts), o1 = kCB * (ob * (p + 1) / pl.parts), orows = o1 - o0;
  const std::size_t m_e = static_cast<std::size_t>(orows) * chunk + 16;
  float* m = tl_m.get(36 * m_e);
  float* dus = du + s * pl.du_floats;
  for (int e = 0; e < 36; ++e) {
    std::fill(dus + (static_cast<std::size_t>(e) * co8 + o0) * ci8, dus + (static_cast<std::size_t>(e) * co8 + o1) * ci8,
              0.f);
    for (int o = std::max(co, o0); o < o1; ++o)  // the block's rows past the last channel
      std::fill(m + e * m_e + static_cast<std::size_t>(o - o0) * chunk,
                m + e * m_e + static_cast<std::size_t>(o - o0 + 1) * chunk, 0.f);
  }
  const long c_begin = pl.chunks * s / pl.slots, c_end = pl.chunks * (s + 1) / pl.slots;
  for (long c = c_begin; c < c_end; ++c) {
    const int img = static_cast<int>(c / (static_cast<long>(g.th) * pl.per_row));
    const int ty = static_cast<int>(c / pl.per_row % g.th), t0 = static_cast<int>(c % pl.per_row) * chunk;
    const int tiles = std::min(chunk, pl.span - t0);
    interleave_rows(rows, cols, in, img, g, ty, t0);
    for (int t = 0; t < tiles; ++t)
      for (int cg = 0; cg < pl.cgs; ++cg)
        input_tile_interleaved(v + static_cast<std::size_t>(t) * ci8 + 8 * cg, pl.v_e,
                               rows + static_cast<std::size_t>(cg) * 6 * cols * 8, cols, t);
    for (int o = o0; o < std::min(co, o1); ++o)
      for (int q = 0; q < tiles; q += 8)
        grad_tile(m + static_cast<std::size_t>(o - o0) * chunk + q, m_e,
                  pg + (static_cast<std::size_t>(img) * co + o) * g.plane, g, ty, t0 + q);
    for (int e = 0; e < 36; ++e)
      for (int o = o0; o < o1; o += 4)
        du_rows4(dus + (static_cast<std::size_t>(e) * co8 + o) * ci8, m + e * m_e + static_cast<std::size_t>(o - o0) * chunk,
                 v + e * pl.v_e, pl, tiles);
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

// d_weight += G^T dU G per kernel, in double: 4 input channels in the lanes of a double vector
// (contiguous in dU), each lane doing the scalar sums in their order (multiply, then add; no
// FMA), the arithmetic of the AVX-512 kernel's lanes.
void add_weight_grad_from_du(float* d_weight, const float* du, const ChunkPlan& pl) {
  static constexpr double G[6][3] = {{1.0 / 4, 0, 0},
                                     {-1.0 / 6, -1.0 / 6, -1.0 / 6},
                                     {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                     {1.0 / 24, 1.0 / 12, 1.0 / 6},
                                     {1.0 / 24, -1.0 / 12, 1.0 / 6},
                                     {0, 0, 1}};
  const int ci = pl.ci, ci8 = pl.ci8;
  const std::size_t du_e = static_cast<std::size_t>(pl.co8) * ci8;
  const int c_blocks = (ci + 3) / 4;
  parallel_for(pl.co * c_blocks, pl.par, [&](long ocl) {
    const int oc = static_cast<int>(ocl), o = oc / c_blocks, c0 = oc % c_blocks * 4, nc = std::min(4, ci - c0);
    const float* d = du + static_cast<std::size_t>(o) * ci8 + c0;  // ci8 >= c0 + 4: the lanes past ci read zeros
    __m256d t[6][3];  // dU G
    for (int a = 0; a < 6; ++a) {
      __m256d x[6];
      for (int bb = 0; bb < 6; ++bb) x[bb] = _mm256_cvtps_pd(_mm_loadu_ps(d + (a * 6 + bb) * du_e));
      for (int kw = 0; kw < 3; ++kw) {
        __m256d acc = _mm256_setzero_pd();
        for (int bb = 0; bb < 6; ++bb) acc = _mm256_add_pd(acc, _mm256_mul_pd(x[bb], _mm256_set1_pd(G[bb][kw])));
        t[a][kw] = acc;
      }
    }
    alignas(32) double r[9][4];
    for (int kh = 0; kh < 3; ++kh)
      for (int kw = 0; kw < 3; ++kw) {
        __m256d acc = _mm256_setzero_pd();
        for (int a = 0; a < 6; ++a) acc = _mm256_add_pd(acc, _mm256_mul_pd(_mm256_set1_pd(G[a][kh]), t[a][kw]));
        _mm256_store_pd(r[kh * 3 + kw], acc);
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
    float* rows = tl_rows.get(static_cast<std::size_t>(pl.cgs) * 6 * pl.cols * 8);
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

}  // namespace lidarsim::nn::detail::avx2

#endif
