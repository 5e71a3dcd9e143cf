// GCC 12's AVX-512 intrinsic headers trip its own -W(maybe-)uninitialized (see conv3x3.cpp).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/conv3x3_bf16.h"

#include "nn/conv3x3.h"
#include "nn/conv3x3_amx.h"
#include "nn/bf16_round.h"
#include "nn/big_alloc.h"
#include "nn/cpu_features.h"
#include "nn/parallel.h"
#include "nn/staged_tile.h"
#include "nn/weight_cache.h"
#include "nn/winograd.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <new>

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>
#endif

namespace lidarsim::nn::detail {

bool conv3x3_bf16_available() { return isa_at_least(Isa::avx512_bf16); }

#if !LIDARSIM_AVX512_KERNELS
void conv3x3_bf16_forward_cat(float*, const float*, int, const float*, int, int, int, int, const float*, const float*,
                              int, bool, WeightCache*) {}
bool conv3x3_takes_bf16(int, int, int, int, int, Conv3x3Path) { return false; }
#else

// Only the functions marked so use AVX-512 BF16 instructions (all in namespace avx512_bf16, as
// the ISA scan of tests/isa expects); they run only after the CPU check, so the rest of the build
// needs no such flags.
#define LIDARSIM_BF16_TARGET __attribute__((target("avx512f,avx512bw,avx512bf16")))

bool conv3x3_takes_bf16(int n, int ci, int co, int h, int w, Conv3x3Path path) {
  // Path direct: bf16 everywhere; winograd: Winograd (fp32) wherever it applies.
  if (path == Conv3x3Path::winograd && winograd_available()) return false;
  // With AMX every layer: the AMX kernel beat fp32 Winograd on each of unet-ref's (conv3x3_takes_amx).
  if (conv3x3_takes_amx(n, ci, co, h, w)) return true;
  // The fp32 rule's 16-channel Winograd layers (enc1.conv1) run faster still in bf16 (1.2-1.3x at
  // batch 4, even at batch 1).
  if (!conv3x3_takes_winograd(ci, co, path) || std::min(ci, co) < 32) return true;
  // Where the fp32 rule takes Winograd, from bench_conv3x3 --forward-only (unet-ref, batch 1
  // and 4, CPU time): bf16 took 1.6-2.2x less time than the fp32 direct kernel on every layer,
  // and less than Winograd at 1,024 pixels per channel (1.1x, its few tiles) and at 65,536
  // (1.3x, its transforms' memory traffic), more at 4,096 and 16,384 (0.75-1.0x).
  const long pixels = static_cast<long>(n) * h * w;
  return pixels < 2048 || pixels >= 32768;
}

namespace avx512_bf16 {
namespace {

constexpr int kCB = 8;            // output channels per register block
constexpr int kNV = 3;            // 16-lane vectors per strip
constexpr int kStrip = 16 * kNV;  // pixels per strip
constexpr int kChunkStrips = 8;   // strips per task (the staging tile stays in L1)
constexpr int kTile = kStrip * kChunkStrips;
constexpr int kFront = 16;     // zero lanes before each padded plane
constexpr int kPrefetch = 48;  // lanes ahead to prefetch
constexpr int kPadPrefetch = 256;  // source floats ahead to prefetch in pad_pair

// The padded layout of conv3x3.cpp, in 32-bit lanes (one pixel of a channel pair each): rows of
// ws = w + 2 lanes, h + 2 rows, kFront zeros before and slack after; index q = (y + 1) ws + x + 1.
struct Geom {
  int h, w, ws;
  std::size_t stride;  // lanes per padded plane, a multiple of 16
  int q0, q_end, qa;   // first valid index, one past the last, q0 rounded down to 16
  Geom(int h_, int w_) : h(h_), w(w_), ws(w_ + 2) {
    stride = kFront + ((static_cast<std::size_t>(h + 2) * ws + 15) / 16) * 16 + 64;
    q0 = ws + 1;
    q_end = h * ws + w + 1;
    qa = q0 / 16 * 16;
  }
};

using Buf = GrowArray<std::uint32_t>;  // scratch of 32-bit lanes (channel pairs)
thread_local Buf tl_pad, tl_wpack;

// Weights [co, ci, 3, 3] -> [out blocks][ci pairs][9][kCB] lanes {bf16 w[o][2p][k], w[o][2p+1][k]}
// (channel 2p in the low half, as in the input lanes), zero past the last channel.
void pack_weights(std::uint32_t* dst, const float* w, int co, int ci) {
  const int blocks = (co + kCB - 1) / kCB, pairs = (ci + 1) / 2;
  for (int b = 0; b < blocks; ++b)
    for (int p = 0; p < pairs; ++p)
      for (int k = 0; k < 9; ++k)
        for (int j = 0; j < kCB; ++j) {
          const int o = b * kCB + j;
          std::uint32_t lo = 0, hi = 0;
          if (o < co) {
            lo = bf16_bits(w[(static_cast<std::size_t>(o) * ci + 2 * p) * 9 + k]);
            if (2 * p + 1 < ci) hi = bf16_bits(w[(static_cast<std::size_t>(o) * ci + 2 * p + 1) * 9 + k]);
          }
          dst[((static_cast<std::size_t>(b) * pairs + p) * 9 + k) * kCB + j] = lo | hi << 16;
        }
}

// One padded plane of the channel pair (c0, c1) (c1 may be null: zeros), planes [h, w].
LIDARSIM_BF16_TARGET void pad_pair(std::uint32_t* dst, const float* c0, const float* c1, const Geom& g) {
  // Word 2i of the result takes word i of the conversion (c0), word 2i + 1 word 16 + i (c1).
  alignas(64) static const std::uint16_t kInterleave[32] = {0, 16, 1, 17, 2,  18, 3,  19, 4,  20, 5,
                                                            21, 6, 22, 7, 23, 8, 24, 9,  25, 10, 26,
                                                            11, 27, 12, 28, 13, 29, 14, 30, 15, 31};
  const __m512i idx = _mm512_load_si512(kInterleave);
  std::fill(dst, dst + kFront + g.ws + 1, 0u);
  std::uint32_t* d = dst + kFront;
  for (int y = 0; y < g.h; ++y) {
    std::uint32_t* row = d + static_cast<std::size_t>(y + 1) * g.ws + 1;
    const float* r0 = c0 + static_cast<std::size_t>(y) * g.w;
    const float* r1 = c1 ? c1 + static_cast<std::size_t>(y) * g.w : nullptr;
    for (int x = 0; x < g.w; x += 16) {
      // These loads stalled without (as in winograd.cpp's to_phases); a prefetch cannot fault.
      _mm_prefetch(reinterpret_cast<const char*>(r0 + x + kPadPrefetch), _MM_HINT_T0);
      if (r1) _mm_prefetch(reinterpret_cast<const char*>(r1 + x + kPadPrefetch), _MM_HINT_T0);
      const __mmask16 m = g.w - x >= 16 ? static_cast<__mmask16>(0xffff) : static_cast<__mmask16>((1u << (g.w - x)) - 1);
      const __m512 a = _mm512_maskz_loadu_ps(m, r0 + x);
      const __m512 b = r1 ? _mm512_maskz_loadu_ps(m, r1 + x) : _mm512_setzero_ps();
      const __m512i both = reinterpret_cast<__m512i>(_mm512_cvtne2ps_pbh(b, a));  // low 16 words: a
      _mm512_mask_storeu_epi32(row + x, m, _mm512_permutexvar_epi16(idx, both));
    }
    row[g.w] = 0;
    row[g.w + 1] = 0;  // left border of the next row
  }
  std::fill(d + static_cast<std::size_t>(g.h + 1) * g.ws + 1, dst + g.stride, 0u);
}

// One strip: kCB output channels x kStrip pixels from index q of the padded pair planes.
LIDARSIM_BF16_TARGET inline void strip_kernel(float* stage, const std::uint32_t* pin, std::size_t pstride,
                                              const std::uint32_t* wb, int pairs, int ws) {
  __m512 acc[kCB][kNV];
  for (int b = 0; b < kCB; ++b)
    for (int v = 0; v < kNV; ++v) acc[b][v] = _mm512_setzero_ps();
  const std::ptrdiff_t off[9] = {-ws - 1, -ws, -ws + 1, -1, 0, 1, ws - 1, ws, ws + 1};
  for (int c = 0; c < pairs; ++c) {
    const std::uint32_t* p = pin + c * pstride;
    const std::uint32_t* wc = wb + static_cast<std::size_t>(c) * 9 * kCB;
    for (int r = 0; r < 3; ++r)  // the next strip's three rows
      for (int v = 0; v < kNV + 1; ++v)
        _mm_prefetch(reinterpret_cast<const char*>(p + off[3 * r] + kPrefetch + 16 * v), _MM_HINT_T0);
    for (int k = 0; k < 9; ++k) {
      const std::uint32_t* s = p + off[k];
      __m512bh x[kNV];
      for (int v = 0; v < kNV; ++v) x[v] = reinterpret_cast<__m512bh>(_mm512_loadu_si512(s + 16 * v));
      for (int b = 0; b < kCB; ++b) {
        const __m512bh wv = reinterpret_cast<__m512bh>(_mm512_set1_epi32(static_cast<int>(wc[k * kCB + b])));
        for (int v = 0; v < kNV; ++v) acc[b][v] = _mm512_dpbf16_ps(acc[b][v], x[v], wv);
      }
    }
  }
  for (int b = 0; b < kCB; ++b)
    for (int v = 0; v < kNV; ++v) _mm512_store_ps(stage + b * kTile + 16 * v, acc[b][v]);
}

// One task: the strips of one pixel chunk for one block of output channels, staged in L1 and
// written out with bias and ReLU.
LIDARSIM_BF16_TARGET void conv_task(float* out, int co, const std::uint32_t* pimg, int pairs, const Geom& g,
                                    const std::uint32_t* wb, const float* bias, bool relu, int chunk, int b,
                                    int strips) {
  alignas(64) float stage[kCB * kTile];
  const int s_begin = chunk * kChunkStrips, s_end = std::min(strips, s_begin + kChunkStrips);
  for (int s = s_begin; s < s_end; ++s)
    strip_kernel(stage + (s - s_begin) * kStrip, pimg + g.qa + s * kStrip, g.stride, wb, pairs, g.ws);
  const std::size_t oplane = static_cast<std::size_t>(g.h) * g.w;
  write_staged_tile([&](int o) { return out + o * oplane; }, stage, kTile, b * kCB, std::min(kCB, co - b * kCB), bias,
                    relu, g.qa + s_begin * kStrip, g.qa + s_end * kStrip, g.h, g.w, g.ws);
}

}  // namespace
}  // namespace avx512_bf16

void conv3x3_bf16_forward_cat(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                              const float* weight, const float* bias, int co, bool relu, WeightCache* cache) {
  using namespace avx512_bf16;
  const Geom g(h, w);
  const int ci = ca + cb, pairs = (ci + 1) / 2;
  const std::size_t plane = static_cast<std::size_t>(h) * w;
  const auto channel = [&](int img, int c) {
    return c < ca ? a + (static_cast<std::size_t>(img) * ca + c) * plane
                  : b + (static_cast<std::size_t>(img) * cb + (c - ca)) * plane;
  };
  std::uint32_t* pin = tl_pad.get(g.stride * pairs * n);
  const bool pad_par = static_cast<std::size_t>(n) * ci * plane > (1u << 15);
  parallel_for(n * pairs, pad_par, [&](long tl) {
    const int t = static_cast<int>(tl), img = t / pairs, p = t % pairs;
    pad_pair(pin + t * g.stride, channel(img, 2 * p), 2 * p + 1 < ci ? channel(img, 2 * p + 1) : nullptr, g);
  });
  const int blocks = (co + kCB - 1) / kCB;
  const std::size_t wp_lanes = static_cast<std::size_t>(blocks) * kCB * pairs * 9;
  bool valid = false;
  std::uint32_t* wp = cache ? static_cast<std::uint32_t*>(cache->get(WeightForm::bf16, weight,
                                                                      static_cast<std::size_t>(co) * ci * 9, co, ci,
                                                                      wp_lanes * 4, &valid))
                             : tl_wpack.get(wp_lanes);
  if (!valid) pack_weights(wp, weight, co, ci);
  const int strips = (g.q_end - g.qa + kStrip - 1) / kStrip;
  const int chunks = (strips + kChunkStrips - 1) / kChunkStrips;
  const bool par = 2.0 * n * (g.q_end - g.q0) * ci * 9 * co > 2e6;
  parallel_for(n * chunks * blocks, par, [&](long tl) {
    const int task = static_cast<int>(tl);
    const int img = task / (chunks * blocks), chunk = (task / blocks) % chunks, blk = task % blocks;
    conv_task(out + static_cast<std::size_t>(img) * co * plane, co,
              pin + static_cast<std::size_t>(img) * pairs * g.stride + kFront, pairs, g,
              wp + static_cast<std::size_t>(blk) * pairs * 9 * kCB, bias, relu, chunk, blk, strips);
  });
}

#endif

}  // namespace lidarsim::nn::detail
