// GCC 12's AVX-512 intrinsic headers trip its own -W(maybe-)uninitialized (see conv3x3.cpp).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/conv3x3_amx.h"

#include "nn/avx512_util.h"
#include "nn/conv3x3_amx_layout.h"
#include "nn/big_alloc.h"
#include "nn/conv3x3_bf16.h"
#include "nn/cpu_features.h"
#include "nn/parallel.h"
#include "nn/staged_tile.h"
#include "nn/weight_cache.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>
#endif

namespace lidarsim::nn::detail {

bool conv3x3_amx_available() { return isa_at_least(Isa::amx_bf16); }

void conv3x3_bf16_dispatch(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                           const float* weight, const float* bias, int co, bool relu, WeightCache* cache) {
  if (conv3x3_takes_amx(n, ca + cb, co, h, w))
    conv3x3_amx_forward_cat(out, a, ca, b, cb, n, h, w, weight, bias, co, relu, cache);
  else
    conv3x3_bf16_forward_cat(out, a, ca, b, cb, n, h, w, weight, bias, co, relu, cache);
}

#if !LIDARSIM_AVX512_KERNELS
void conv3x3_amx_forward_cat(float*, const float*, int, const float*, int, int, int, int, const float*, const float*,
                             int, bool, WeightCache*) {}
bool conv3x3_takes_amx(int, int, int, int, int) { return false; }
#else

// Every layer bf16 inference takes, and with AMX it takes them all (conv3x3_takes_bf16): from
// bench_conv3x3 --forward-only (unet-ref, batch 1 and 4, CPU time of 2 threads; Intel Xeon,
// Sapphire Rapids class, 2 cores shared with other work, load average 1.1-3.3; four runs over
// the kernel's versions), AMX took 1.5-17x less time than the AVX-512 BF16 kernel and less than
// fp32 Winograd on every layer: 1.05-1.6x on enc1.conv1 (3 -> 16 at 64 x 1024, 1.2-1.5x in the
// last run), 1.3-6x elsewhere.
bool conv3x3_takes_amx(int, int, int, int, int) { return conv3x3_amx_available(); }

namespace {

using namespace amx_layout;

constexpr int kM = 16;            // pixels per C tile
constexpr int kChunk = 256;       // pixels per task of a small image (a multiple of both blocks)
constexpr int kStageStride = 64;  // floats per output channel in the write-out stage

// Per calling thread (nn/big_alloc.h): the staged bf16 input and the packed weights' pairs.
thread_local GrowArray<std::uint16_t> tl_in;
thread_local GrowArray<std::uint32_t> tl_wpack;

}  // namespace

// Everything from here to the pop uses AVX-512 and AMX; only the functions of namespace
// avx512_amx do (the ISA scan, tests/isa, accepts them by that name).
#if defined(__clang__)
#pragma clang attribute push(                                                                            \
    __attribute__((target("avx512f,avx512bw,avx512vl,avx512dq,avx512bf16,amx-tile,amx-bf16"))), \
    apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx512f,avx512bw,avx512vl,avx512dq,avx512bf16,amx-tile,amx-bf16")
#endif
namespace avx512_amx {
namespace {

// Palette 1, all 8 tiles 16 rows x 64 bytes: C (16 pixels x 16 fp32), A (16 pixels x 32 bf16),
// B (16 channel pairs x 16 outputs x 2 bf16) all have that shape. A constant in memory: GCC's
// _tile_loadconfig tells the compiler it reads 8 bytes only, so stores to a local config
// could be dropped (they were: SIGILL at the first tile instruction).
struct alignas(64) TileConfig {
  std::uint8_t palette, start_row, reserved[14];
  std::uint16_t colsb[16];
  std::uint8_t rows[16];
};
constexpr TileConfig kTileConfig = {1, 0, {}, {64, 64, 64, 64, 64, 64, 64, 64}, {16, 16, 16, 16, 16, 16, 16, 16}};
static_assert(sizeof(TileConfig) == 64, "the 64-byte tile configuration");

void load_tile_config() { _tile_loadconfig(&kTileConfig); }

// ps 4 (ci <= 4): 16 pixels from two conversions (channels 0 | 1 and 2 | 3, 16 words each) and
// two word permutes into pixel order, instead of a 16 x 16 transpose of mostly zero channels.
void stage_pixels4(std::uint16_t* px, const float* const* ch, const Geom& g, std::size_t at) {
  alignas(64) std::uint16_t idx[2][32];
  for (int h = 0; h < 2; ++h)
    for (int p = 0; p < 8; ++p)
      for (int k = 0; k < 4; ++k) idx[h][4 * p + k] = static_cast<std::uint16_t>(16 * k + 8 * h + p);
  const __m512i lo = _mm512_load_si512(idx[0]), hi = _mm512_load_si512(idx[1]);
  for (int x0 = 0; x0 < g.w; x0 += 16) {
    const int nv = std::min(16, g.w - x0);
    const __mmask16 m = static_cast<__mmask16>((1u << nv) - 1);
    __m512 v[4];
    for (int c = 0; c < 4; ++c) v[c] = c < g.ci ? _mm512_maskz_loadu_ps(m, ch[c] + at + x0) : _mm512_setzero_ps();
    const __m512i a = reinterpret_cast<__m512i>(_mm512_cvtne2ps_pbh(v[1], v[0]));  // words 16 c + p
    const __m512i b = reinterpret_cast<__m512i>(_mm512_cvtne2ps_pbh(v[3], v[2]));  // (c - 2 in b)
    const auto words = [](int pixels) {
      return pixels >= 8 ? static_cast<__mmask32>(0xffffffffu) : static_cast<__mmask32>((1u << (4 * pixels)) - 1);
    };
    _mm512_mask_storeu_epi16(px + x0 * 4, words(nv), _mm512_permutex2var_epi16(a, lo, b));
    if (nv > 8) _mm512_mask_storeu_epi16(px + x0 * 4 + 32, words(nv - 8), _mm512_permutex2var_epi16(a, hi, b));
  }
}

// Row y of the input (channel pointers ch[0, ci) of one image) staged at `row`, the place of
// pixel (y, -1) in a buffer of the padded layout: its two border pixels zeroed, its w pixels 16 x
// 16 channels at a time, transposed and rounded to bf16 by the hardware conversion (round to
// nearest even, as conv3x3_bf16's); ps < 16: the first ps channels.
void stage_row(std::uint16_t* row, const float* const* ch, const Geom& g, int y) {
  const std::size_t ps = g.ps;
  std::memset(row, 0, ps * 2);
  std::memset(row + (g.w + 1) * ps, 0, ps * 2);
  row += ps;  // pixel (y, 0)
  const std::size_t at = static_cast<std::size_t>(y) * g.w;
  if (g.ps == 4) {
    stage_pixels4(row, ch, g, at);
    return;
  }
  const __mmask16 cmask = static_cast<__mmask16>(g.ps >= 16 ? 0xffffu : (1u << g.ps) - 1);
  for (int x0 = 0; x0 < g.w; x0 += 16) {
    const int nv = std::min(16, g.w - x0);
    const __mmask16 m = static_cast<__mmask16>((1u << nv) - 1);
    std::uint16_t* px = row + x0 * ps;
    for (int c0 = 0; c0 < g.ps; c0 += 16) {
      __m512 r[16], col[16];
      for (int j = 0; j < 16; ++j)
        r[j] = c0 + j < g.ci ? _mm512_maskz_loadu_ps(m, ch[c0 + j] + at + x0) : _mm512_setzero_ps();
      avx512::transpose16(r, col);  // col[p]: pixel p's 16 channels
      for (int p = 0; p < nv; ++p)
        _mm256_mask_storeu_epi16(px + p * ps + c0, cmask, reinterpret_cast<__m256i>(_mm512_cvtneps_pbh(col[p])));
    }
  }
}

// C tile t holds 16 pixels (rows) x 16 outputs; into the stage as outputs (rows) x pixels.
void tile_to_stage(float* stage, const float* c) {
  __m512 r[16], col[16];
  for (int i = 0; i < 16; ++i) r[i] = _mm512_load_ps(c + 16 * i);
  avx512::transpose16(r, col);
  for (int o = 0; o < 16; ++o) _mm512_store_ps(stage + o * kStageStride, col[o]);
}

// 32 pixels from xq (staged pixel q) x 32 outputs (B tiles of two output blocks): C tiles 0-3 (pixel half i, output
// half j: tile 2 i + j), A tiles 4-5, B tiles 6-7; every output sums its steps in order, so the
// bits do not depend on the block or the thread that computes it.
void block_2x2(float* stage, const std::uint16_t* xq, const Geom& g, const std::uint32_t* w0,
               const std::uint32_t* w1) {
  const long stride = g.ps * 2L, a16 = 16L * g.ps;  // bytes per pixel; elements per 16 pixels
  const long* aoff = g.aoff.data();
  const int steps = g.steps();
  _tile_zero(0);
  _tile_zero(1);
  _tile_zero(2);
  _tile_zero(3);
  for (int s = 0; s < steps; ++s) {
    const std::uint16_t* a = xq + aoff[s];
    _tile_loadd(4, a, stride);
    _tile_loadd(6, w0 + s * 256, 64);
    _tile_loadd(5, a + a16, stride);
    _tile_loadd(7, w1 + s * 256, 64);
    _tile_dpbf16ps(0, 4, 6);
    _tile_dpbf16ps(1, 4, 7);
    _tile_dpbf16ps(2, 5, 6);
    _tile_dpbf16ps(3, 5, 7);
  }
  alignas(64) float c[4][256];
  _tile_stored(0, c[0], 64);
  _tile_stored(1, c[1], 64);
  _tile_stored(2, c[2], 64);
  _tile_stored(3, c[3], 64);
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) tile_to_stage(stage + 16 * j * kStageStride + 16 * i, c[2 * i + j]);
}

// 64 pixels from xq x 16 outputs (one output block: co 16, or the odd last block): C tiles 0-3
// (pixel quarters), B tile 4, A tiles 5-7 in turn; the same sum order as block_2x2.
void block_4x1(float* stage, const std::uint16_t* xq, const Geom& g, const std::uint32_t* w0) {
  const long stride = g.ps * 2L, a16 = 16L * g.ps;
  const long* aoff = g.aoff.data();
  const int steps = g.steps();
  _tile_zero(0);
  _tile_zero(1);
  _tile_zero(2);
  _tile_zero(3);
  for (int s = 0; s < steps; ++s) {
    const std::uint16_t* a = xq + aoff[s];
    _tile_loadd(4, w0 + s * 256, 64);
    _tile_loadd(5, a, stride);
    _tile_loadd(6, a + a16, stride);
    _tile_loadd(7, a + 2 * a16, stride);
    _tile_dpbf16ps(0, 5, 4);
    _tile_dpbf16ps(1, 6, 4);
    _tile_loadd(5, a + 3 * a16, stride);
    _tile_dpbf16ps(2, 7, 4);
    _tile_dpbf16ps(3, 5, 4);
  }
  alignas(64) float c[4][256];
  _tile_stored(0, c[0], 64);
  _tile_stored(1, c[1], 64);
  _tile_stored(2, c[2], 64);
  _tile_stored(3, c[3], 64);
  for (int i = 0; i < 4; ++i) tile_to_stage(stage + 16 * i, c[i]);
}

// Pixels [qs, qe) of one image (staged pixel qs at xs) for output blocks 2 grp and 2 grp + 1 (or
// the last block alone), written out with bias and ReLU.
void run_blocks(float* out, const std::uint16_t* xs, const Geom& g, const std::uint32_t* wp, const float* bias,
                bool relu, int co, int grp, long qs, long qe) {
  alignas(64) float stage[2 * kN * kStageStride];
  const int blocks = (co + kN - 1) / kN, b0 = 2 * grp, nb = std::min(2, blocks - b0);
  const std::size_t wblock = static_cast<std::size_t>(g.steps()) * 16 * kN;
  const std::uint32_t* w0 = wp + b0 * wblock;
  const int step = nb == 2 ? 2 * kM : 4 * kM;
  const std::size_t oplane = static_cast<std::size_t>(g.h) * g.w;
  for (long q = qs; q < qe; q += step) {
    const std::uint16_t* xq = xs + (q - qs) * g.ps;
    if (nb == 2)
      block_2x2(stage, xq, g, w0, w0 + wblock);
    else
      block_4x1(stage, xq, g, w0);
    write_staged_tile([&](int o) { return out + o * oplane; }, stage, kStageStride, b0 * kN,
                      std::min(nb * kN, co - b0 * kN), bias, relu, static_cast<int>(q),
                      static_cast<int>(std::min(q + step, qe)), g.h, g.w, g.ws);
  }
}

// Rows [y0, y0 + kBand) of one image: staged with their halo rows into buf (a thread's own, kept in
// its L2 cache: the staged input never goes through memory), then every output group.
void run_band(float* out, std::uint16_t* buf, const float* const* ch, const Geom& g, const std::uint32_t* wp,
              const float* bias, bool relu, int co, int y0) {
  const int y1 = std::min(g.h, y0 + kBand);
  const std::size_t row = static_cast<std::size_t>(g.ws) * g.ps;  // elements per padded row
  // buf row r is padded row y0 + r (image row y0 + r - 1); rows past y1 + 1 only feed discarded
  // pixels of the last block but are zeroed all the same.
  for (int y = y0 - 1; y <= y1; ++y) {
    std::uint16_t* r = buf + (y - y0 + 1) * row;
    if (y < 0 || y >= g.h)
      std::memset(r, 0, row * 2);
    else
      stage_row(r, ch, g, y);
  }
  std::memset(buf + (y1 - y0 + 2) * row, 0, (band_pixels(g) * g.ps - (y1 - y0 + 2) * row) * 2);
  const long qs = static_cast<long>(y0 + 1) * g.ws + 1, qe = static_cast<long>(y1) * g.ws + g.w + 1;
  const int groups = ((co + kN - 1) / kN + 1) / 2;
  for (int grp = 0; grp < groups; ++grp)
    run_blocks(out, buf + (qs - static_cast<long>(y0) * g.ws) * g.ps, g, wp, bias, relu, co, grp, qs, qe);
}

}  // namespace

void forward(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w, const float* weight,
             const float* bias, int co, bool relu, WeightCache* cache) {
  const int ci = ca + cb;
  const Geom g(h, w, ci);
  const std::size_t plane = static_cast<std::size_t>(h) * w;
  std::vector<const float*> ch(static_cast<std::size_t>(n) * ci);
  for (int img = 0; img < n; ++img)
    for (int c = 0; c < ci; ++c)
      ch[static_cast<std::size_t>(img) * ci + c] = c < ca ? a + (static_cast<std::size_t>(img) * ca + c) * plane
                                                          : b + (static_cast<std::size_t>(img) * cb + c - ca) * plane;
  const int blocks = (co + kN - 1) / kN, groups = (blocks + 1) / 2;
  const std::size_t wbytes = static_cast<std::size_t>(blocks) * g.steps() * 16 * kN * 4;
  bool valid = false;
  auto* wp = static_cast<std::uint32_t*>(
      cache ? cache->get(WeightForm::amx, weight, static_cast<std::size_t>(co) * ci * 9, co, ci, wbytes, &valid)
            : tl_wpack.get(wbytes / 4));
  if (!valid) pack_weights(wp, weight, co, g);
  const bool par = 2.0 * n * (g.q_end - g.q0) * ci * 9 * co > 2e6;
  if (h >= 2 * kBand) {
    // Large images: one task per band of rows, staged by the thread that computes it.
    const int bands = (h + kBand - 1) / kBand, threads = par ? team_threads() : 1;
    const std::size_t band_elems = band_pixels(g) * g.ps;
    std::uint16_t* bufs = tl_in.get(band_elems * threads);
    parallel_shared(static_cast<long>(n) * bands, par, [&](int tid, int nt, Shares& shares) {
      if (tid >= threads) return;  // (a team grown since: the others take this thread's share)
      load_tile_config();
      shares.run(tid, nt, [&](long t) {
        const int img = static_cast<int>(t / bands), band = static_cast<int>(t % bands);
        run_band(out + static_cast<std::size_t>(img) * co * plane, bufs + tid * band_elems,
                 ch.data() + static_cast<std::size_t>(img) * ci, g, wp, bias, relu, co, band * kBand);
      });
      _tile_release();
    });
    return;
  }
  // Small images: the whole input staged first (in parallel over rows), then tasks of kChunk
  // pixels x one output group.
  const std::size_t img_elems = static_cast<std::size_t>(g.pixels) * g.ps, row = static_cast<std::size_t>(g.ws) * g.ps;
  std::uint16_t* x = tl_in.get(img_elems * n);
  const bool stage_par = static_cast<std::size_t>(n) * ci * plane > (1u << 15);
  parallel_for(static_cast<long>(n) * h, stage_par, [&](long t) {
    const int img = static_cast<int>(t / h), y = static_cast<int>(t % h);
    std::uint16_t* xi = x + img * img_elems;
    if (y == 0) std::memset(xi, 0, row * 2);  // the top border row
    if (y == h - 1) std::memset(xi + (h + 1) * row, 0, (img_elems - (h + 1) * row) * 2);  // bottom row, slack
    stage_row(xi + (y + 1) * row, ch.data() + static_cast<std::size_t>(img) * ci, g, y);
  });
  const int chunks = static_cast<int>((g.q_end - g.q0 + kChunk - 1) / kChunk);
  const long tasks = static_cast<long>(n) * groups * chunks;
  // Tasks ordered image, output group, chunk: a thread's run of tasks keeps one group's weights
  // in cache. Each thread configures its own tiles once per call and releases them at the end.
  parallel_shared(tasks, par, [&](int tid, int nt, Shares& shares) {
    load_tile_config();
    shares.run(tid, nt, [&](long t) {
      const int img = static_cast<int>(t / (static_cast<long>(groups) * chunks));
      const int grp = static_cast<int>(t / chunks % groups), chunk = static_cast<int>(t % chunks);
      const long qs = g.q0 + static_cast<long>(chunk) * kChunk, qe = std::min(g.q_end, qs + kChunk);
      run_blocks(out + static_cast<std::size_t>(img) * co * plane, x + img * img_elems + qs * g.ps, g, wp, bias, relu,
                 co, grp, qs, qe);
    });
    _tile_release();
  });
}

}  // namespace avx512_amx
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif

void conv3x3_amx_forward_cat(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                             const float* weight, const float* bias, int co, bool relu, WeightCache* cache) {
  avx512_amx::forward(out, a, ca, b, cb, n, h, w, weight, bias, co, relu, cache);
}

#endif

}  // namespace lidarsim::nn::detail
