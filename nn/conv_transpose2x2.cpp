// GCC 12's AVX-512 intrinsic headers initialise "undefined" vectors from themselves, which its
// own -W(maybe-)uninitialized then reports wherever they are inlined.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/conv_transpose2x2.h"

#include <algorithm>
#include <cstddef>
#include <vector>

#include "nn/big_alloc.h"
#include "nn/cpu_features.h"
#include "nn/parallel.h"

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>
#endif

namespace lidarsim::nn::detail {
bool conv_transpose2x2_available() { return isa_at_least(Isa::avx512); }
}  // namespace lidarsim::nn::detail

#if !LIDARSIM_AVX512_KERNELS
namespace lidarsim::nn::detail::avx512 {
void conv_transpose2x2_forward_fast(float*, const float*, int, int, int, int, const float*, const float*, int, int,
                                    int) {}
}  // namespace lidarsim::nn::detail::avx512
#else

namespace lidarsim::nn::detail::avx512 {
namespace {
// 32 pixels of every input channel, per thread, 64-byte aligned for the aligned AVX-512 stores
// (Eigen's aligned_allocator aligns to 32 bytes only in an AVX2 build). Outside the AVX-512
// region: its construction and destruction are baseline code.
thread_local GrowBuffer tl_pixels;
// The weights regrouped by output-channel block: scratch of one call, per calling thread (a pure
// cache; models running in several threads at once must not share it). Workers write through
// the pointer taken on the caller, never through this object.
thread_local std::vector<float> tl_taps;
}  // namespace
}  // namespace lidarsim::nn::detail::avx512

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512 {

namespace {

// Below this many FLOPs a parallel region costs more than it saves (as in nn/layers.cpp).
constexpr double kParallelFlops = 2e6;

// The first n of 16 lanes (n clamped to 0..16).
inline __mmask16 first_lanes(int n) {
  n = std::clamp(n, 0, 16);
  return static_cast<__mmask16>((1u << n) - 1);
}

// Output rows 2y and 2y + 1, columns 2 x0 .. 2 x0 + 63, of output channels o .. o + OB - 1: the
// 4 taps of OB channels over 32 input pixels are 4 OB x 2 accumulators (16 registers at OB = 2),
// two input loads and 4 OB weight broadcasts per 8 OB multiply-adds and input channel. xs holds
// the 32 pixels of every input channel side by side and wp the block's taps [ci][4 OB]: both
// are read in order (the input planes themselves sit a power of two apart and would share
// cache sets).
template <int OB>
void forward_block(float* out_img, const float* xs, int ci, int w, int y, int x0, const float* wp, const float* bias,
                   int o, int out_h, int out_w) {
  // Lane i of the low (high) half of the interleave of e and o: e[i/2] or o[i/2] (plus 8 for
  // high), as _mm512_permutex2var_ps indices (16 + j picks lane j of the second operand).
  const __m512i kInterleaveLo = _mm512_set_epi32(23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1, 16, 0);
  const __m512i kInterleaveHi = _mm512_set_epi32(31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8);
  __m512 acc[2][4 * OB];
  for (int v = 0; v < 2; ++v)
    for (int k = 0; k < 4 * OB; ++k) acc[v][k] = _mm512_setzero_ps();
  for (int c = 0; c < ci; ++c, xs += 32, wp += 4 * OB) {
    const __m512 v0 = _mm512_load_ps(xs), v1 = _mm512_load_ps(xs + 16);
    for (int k = 0; k < 4 * OB; ++k) {
      const __m512 wk = _mm512_set1_ps(wp[k]);
      acc[0][k] = _mm512_fmadd_ps(v0, wk, acc[0][k]);
      acc[1][k] = _mm512_fmadd_ps(v1, wk, acc[1][k]);
    }
  }
  for (int j = 0; j < OB; ++j) {
    const __m512 b = _mm512_set1_ps(bias ? bias[o + j] : 0.f);
    for (int a = 0; a < 2; ++a) {
      float* row = out_img + (static_cast<std::size_t>(o + j) * out_h + 2 * y + a) * out_w + 2 * x0;
      for (int v = 0; v < 2; ++v) {
        const int floats = 2 * std::clamp(w - x0 - 16 * v, 0, 16);  // output columns of this vector
        if (floats == 0) break;
        const __m512 e = acc[v][4 * j + 2 * a], od = acc[v][4 * j + 2 * a + 1];
        _mm512_mask_storeu_ps(row + 32 * v, first_lanes(floats),
                              _mm512_add_ps(_mm512_permutex2var_ps(e, kInterleaveLo, od), b));
        _mm512_mask_storeu_ps(row + 32 * v + 16, first_lanes(floats - 16),
                              _mm512_add_ps(_mm512_permutex2var_ps(e, kInterleaveHi, od), b));
      }
    }
  }
}

}  // namespace

void conv_transpose2x2_forward_fast(float* out, const float* in, int n, int ci, int h, int w, const float* weight,
                                    const float* bias, int co, int out_h, int out_w) {
  const std::size_t hw = static_cast<std::size_t>(h) * w, oplane = static_cast<std::size_t>(out_h) * out_w;
  // Taps by block: [o / 2][c][2 channels x 4 taps], then the odd channel out [c][4].
  tl_taps.resize(static_cast<std::size_t>(ci) * co * 4);
  float* const taps_out = tl_taps.data();
  const int pairs = co / 2;
  // On the team too: serially, the deepest layer's 131K taps kept the other thread waiting
  // long enough to fall asleep.
  parallel_for(ci, static_cast<std::size_t>(ci) * co > 4096, [&](long c) {
    for (int o = 0; o < co; ++o) {
      const std::size_t dst = o < 2 * pairs ? (static_cast<std::size_t>(o / 2) * ci + c) * 8 + (o % 2) * 4
                                            : (static_cast<std::size_t>(pairs) * ci * 2 + c) * 4;
      std::copy_n(weight + (static_cast<std::size_t>(c) * co + o) * 4, 4, taps_out + dst);
    }
  });
  const float* taps = taps_out;
  const bool par = 8.0 * n * hw * ci * co > kParallelFlops;
  parallel_for(n * h, par, [&](long task) {
    const int img = static_cast<int>(task / h), y = static_cast<int>(task % h);
    const float* in_img = in + static_cast<std::size_t>(img) * ci * hw;
    float* out_img = out + static_cast<std::size_t>(img) * co * oplane;
    float* xs = tl_pixels.get(static_cast<std::size_t>(ci) * 32);
    for (int x0 = 0; x0 < w; x0 += 32) {
      const __mmask16 m0 = first_lanes(w - x0), m1 = first_lanes(w - x0 - 16);
      const float* ip = in_img + static_cast<std::size_t>(y) * w + x0;
      for (int c = 0; c < ci; ++c, ip += hw) {
        _mm512_store_ps(xs + 32 * c, _mm512_maskz_loadu_ps(m0, ip));
        _mm512_store_ps(xs + 32 * c + 16, _mm512_maskz_loadu_ps(m1, ip + 16));
      }
      for (int p = 0; p < pairs; ++p)
        forward_block<2>(out_img, xs, ci, w, y, x0, taps + static_cast<std::size_t>(p) * ci * 8, bias, 2 * p, out_h,
                         out_w);
      if (co % 2)
        forward_block<1>(out_img, xs, ci, w, y, x0, taps + static_cast<std::size_t>(pairs) * ci * 8, bias, co - 1,
                         out_h, out_w);
    }
    // The zero padding right of the up-sampled rows and, once per image, below them.
    for (int o = 0; o < co; ++o) {
      float* plane = out_img + static_cast<std::size_t>(o) * oplane;
      for (int a = 0; a < 2; ++a) {
        float* row = plane + static_cast<std::size_t>(2 * y + a) * out_w;
        std::fill(row + 2 * w, row + out_w, 0.f);
      }
      if (y == h - 1) std::fill(plane + static_cast<std::size_t>(2 * h) * out_w, plane + oplane, 0.f);
    }
  });
}

}  // namespace lidarsim::nn::detail::avx512
#include "nn/isa_avx512_end.h"

#endif
