// GCC 12's AVX-512 intrinsic headers initialise "undefined" vectors from themselves, which its
// own -W(maybe-)uninitialized then reports wherever they are inlined (Eigen's kernels included).
// The pragma must precede the headers: diagnostics are judged at the header's lines.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/conv3x3.h"

#include <algorithm>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <new>
#include <string>
#include <vector>

#include "common/error.h"
#include "nn/avx512_util.h"
#include "nn/big_alloc.h"
#include "nn/cpu_features.h"
#include "nn/kernel_plan.h"
#include "nn/parallel.h"
#include "nn/weight_cache.h"
#include "nn/staged_tile.h"
#include "nn/winograd.h"

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>
#endif

namespace lidarsim::nn::detail {

namespace {
Conv3x3Path read_path_env() {
  const char* env = std::getenv("LIDARSIM_CONV3X3");
  const std::string v = env ? env : "auto";
  if (v == "auto" || v.empty()) return Conv3x3Path::automatic;
  if (v == "direct") return Conv3x3Path::direct;
  if (v == "winograd") return Conv3x3Path::winograd;
  throw Error("environment: LIDARSIM_CONV3X3: expected direct, winograd or auto, got \"" + v + "\"");
}
// The process default only (nn/conv_settings.h): each call takes the algorithm from its ConvSettings.
Conv3x3Path g_path = read_path_env();
}  // namespace

void set_conv3x3_path(Conv3x3Path path) { g_path = path; }
Conv3x3Path conv3x3_path() { return g_path; }

bool conv3x3_takes_winograd(int ci, int co, Conv3x3Path path) {
  if (!winograd_available() || path == Conv3x3Path::direct) return false;
  if (path == Conv3x3Path::winograd) return true;
  // Measured in the network (LIDARSIM_PROFILE=cpu, one thread, batch 1 and 4), with the weight
  // gradient streaming its tiles (nn/winograd.h): every conv with 16 or more
  // channels on both sides took less time on Winograd in all its passes, the 64 x 1024 ones
  // included (16 -> 16 there: forward 1.2-1.6x, backward 1.1-1.3x; the weight gradient alone
  // 1.6-1.8x in bench_conv3x3), with one exception of 0.5 % of a step (the 4 x 64 level at
  // batch 4: 1.2 ms more of a 240 ms one-thread step). With fewer channels (the first conv,
  // 4 -> 16) the transforms cost more than they save (its weight gradient 0.7x).
  return std::min(ci, co) >= 16;
}

bool conv3x3_avx2_takes_winograd(int ci, int co, int n, int h, int w, Conv3x3Path path) {
  if (!winograd_available() || path == Conv3x3Path::direct) return false;
  if (path == Conv3x3Path::winograd) return true;
  // Measured with bench_conv3x3 --threads 1 (AMD EPYC, Zen 3, AVX2; docs/performance.md) against
  // im2col + Eigen GEMM, on every 3x3 conv of unet-ref at batch 1 and 4: wherever the batch holds
  // 1024 or more pixels per channel, Winograd took less time over the three passes of every layer
  // (the thin first conv, 3 -> 16, included: its gradients 1.5-2.3x, its forward 0.8-0.9x); below,
  // at batch 1 on 4 x 64 maps, its weight transforms, which grow with ci co but not with the
  // pixels, cost more than the products save (forward 0.6-0.9x, weight gradient 0.7-0.8x), while
  // at batch 4 the same layers gain 1.1-1.7x. Fixed from that one CPU, not calibrated where it runs.
  (void)ci, (void)co;
  return static_cast<long>(n) * h * w >= 1024;
}

bool conv3x3_available() { return isa_at_least(Isa::avx512); }

}  // namespace lidarsim::nn::detail

#if !LIDARSIM_AVX512_KERNELS
namespace lidarsim::nn::detail::avx512 {
void conv3x3_forward(float*, const float*, int, int, int, int, const float*, const float*, int, bool,
                     const ConvSettings&) {}
void conv3x3_backward(float*, float*, float*, const float*, const float*, const float*, const float*, int, int, int,
                      int, int, bool, const ConvSettings&) {}
void conv3x3_forward_cat(float*, const float*, int, const float*, int, int, int, int, const float*, const float*, int,
                         bool, const ConvSettings&) {}
void conv3x3_backward_cat(float*, float*, float*, float*, const float*, const float*, const float*, int, const float*,
                          int, const float*, int, int, int, int, bool, const ConvSettings&) {}
}  // namespace lidarsim::nn::detail::avx512
#else

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512 {

namespace {

constexpr int kCB = 8;            // output channels per register block
constexpr int kNV = 3;            // 16-float vectors per strip
constexpr int kStrip = 16 * kNV;  // pixels per strip
#ifndef LIDARSIM_CHUNK_STRIPS
#define LIDARSIM_CHUNK_STRIPS 8
#endif
constexpr int kChunkStrips = LIDARSIM_CHUNK_STRIPS;  // strips per forward task (its staging tile stays in L1)
#ifndef LIDARSIM_WG_CHUNK
#define LIDARSIM_WG_CHUNK 2048
#endif
constexpr int kWgChunk = LIDARSIM_WG_CHUNK;  // pixels per weight-gradient chunk (a multiple of 16)
constexpr int kFront = 16;        // zero floats before each padded plane
#ifndef LIDARSIM_PREFETCH
#define LIDARSIM_PREFETCH 48
#endif
constexpr int kPrefetch = LIDARSIM_PREFETCH;  // floats ahead to prefetch in the forward kernel
#ifndef LIDARSIM_WG_PREFETCH
#define LIDARSIM_WG_PREFETCH 0
#endif
constexpr int kWgPrefetch = LIDARSIM_WG_PREFETCH;  // and in the weight-gradient kernel

// Padded geometry of one h x w plane: rows of ws = w + 2 floats, h + 2 rows, kFront zeros before
// and slack after, so strips that start at an aligned index or run past the last pixel read
// finite zeros. Index q = (y + 1) ws + (x + 1) is pixel (y, x) relative to the plane start.
struct Geom {
  int h, w, ws;
  std::size_t stride;  // floats per padded channel, a multiple of 16 (planes stay 64-byte aligned)
  int q0, q_end;       // first valid index, one past the last
  int qa;              // q0 rounded down to a multiple of 16
  Geom(int h_, int w_) : h(h_), w(w_), ws(w_ + 2) {
    stride = kFront + ((static_cast<std::size_t>(h + 2) * ws + 15) / 16) * 16 + 64;
    q0 = ws + 1;
    q_end = h * ws + w + 1;
    qa = q0 / 16 * 16;
  }
};

// Channels [a (ca of them), b (cb)] of NCHW buffers seen as one: the UNet's concat without a copy.
template <typename T>
struct Cat {
  T* a;
  int ca;
  T* b = nullptr;
  int cb = 0;
  int channels() const { return ca + cb; }
  T* plane(int img, int ch, std::size_t plane_size) const {
    return ch < ca ? a + (static_cast<std::size_t>(img) * ca + ch) * plane_size
                   : b + (static_cast<std::size_t>(img) * cb + (ch - ca)) * plane_size;
  }
};

using Buf = GrowBuffer;  // nn/big_alloc.h

// Scratch of one call, grown to the largest layer and reused (no allocation in steady state). Per
// thread: a pure cache whose contents do not outlive the call, and models that run in several
// threads at once (one FMU instance per lidar) must not share it. Only the calling thread touches
// these objects; the team's workers get the pointers.
thread_local Buf tl_pad_in, tl_pad_g, tl_wpack, tl_sums;

// The sum of rows [0, rows) of a plane (row stride `stride`, w values each; only where mask > 0
// when mask is given, same strides), for the bias gradient, in the order it has always been
// summed: each row from x = 0 up, the row sums added from row 0 down. A row's sum is one chain of
// dependent adds (4 cycles each), so 16 rows run side by side in the lanes of one vector, read
// as transposed 16 x 16 blocks: the same bits as one row at a time.
float plane_sum(const float* src, const float* mask, std::size_t stride, int rows, int w) {
  const __m512 zero = _mm512_setzero_ps();
  float total = 0.f;
  for (int y0 = 0; y0 < rows; y0 += 16) {
    const int nr = std::min(16, rows - y0);
    __m512 acc = zero;
    for (int x0 = 0; x0 < w; x0 += 16) {
      const int valid = std::min(16, w - x0);
      const __mmask16 lm = valid == 16 ? static_cast<__mmask16>(0xffff) : static_cast<__mmask16>((1u << valid) - 1);
      __m512 r[16], col[16];
      for (int k = 0; k < 16; ++k) {  // rows past the last repeat it (their lanes are dropped)
        const std::size_t off = static_cast<std::size_t>(y0 + std::min(k, nr - 1)) * stride + x0;
        const __m512 v = _mm512_maskz_loadu_ps(lm, src + off);
        r[k] = mask ? _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(_mm512_maskz_loadu_ps(lm, mask + off), zero, _CMP_GT_OQ), v)
                    : v;
      }
      transpose16(r, col);
      for (int x = 0; x < valid; ++x) acc = _mm512_add_ps(acc, col[x]);
    }
    alignas(64) float rs[16];
    _mm512_store_ps(rs, acc);
    for (int k = 0; k < nr; ++k) total += rs[k];
  }
  return total;
}

// Copies the n images' planes [h, w] into the padded layout, zero borders and slack included. With mask,
// copies src only where mask > 0 (the ReLU backward).
// With sums, sums[ch] gets the plane's sum (of the masked values), for the bias gradient.
void pad_planes(float* dst, const Cat<const float>& src, const float* mask, int n, const Geom& g, bool parallel,
                float* sums = nullptr) {
  const int per_image = src.channels();
  parallel_for(n * per_image, parallel, [&](long ch) {
    float* d = dst + ch * g.stride;
    const float* s = src.plane(ch / per_image, ch % per_image, static_cast<std::size_t>(g.h) * g.w);
    const float* m = mask ? mask + static_cast<std::size_t>(ch) * g.h * g.w : nullptr;
    std::fill(d, d + kFront + g.ws + 1, 0.f);
    d += kFront;
    for (int y = 0; y < g.h; ++y) {
      float* row = d + static_cast<std::size_t>(y + 1) * g.ws + 1;
      const float* sr = s + static_cast<std::size_t>(y) * g.w;
      if (m) {
        const float* mr = m + static_cast<std::size_t>(y) * g.w;
        for (int x = 0; x < g.w; ++x) row[x] = mr[x] > 0.f ? sr[x] : 0.f;
      } else {
        std::memcpy(row, sr, sizeof(float) * g.w);
      }
      row[g.w] = 0.f;
      row[g.w + 1] = 0.f;  // left border of the next row
    }
    std::fill(d + static_cast<std::size_t>(g.h + 1) * g.ws + 1, dst + (ch + 1) * g.stride, 0.f);
    if (sums) sums[ch] = plane_sum(d + g.ws + 1, nullptr, g.ws, g.h, g.w);  // the copy, still in cache
  });
}

// Packs w [co, ci, 3, 3] into blocks [out_blocks][in][9][kCB], zero-filled past the last output
// channel. transpose_flip packs the input-gradient weights: out = ci, in = co, w[co, ci, 2-kh, 2-kw].
void pack_weights(float* dst, const float* w, int co, int ci, bool transpose_flip) {
  const int out_c = transpose_flip ? ci : co, in_c = transpose_flip ? co : ci;
  const int blocks = (out_c + kCB - 1) / kCB;
  // In parallel: a serial pack of the deepest layers' weights (590K values) left the other
  // thread waiting.
  parallel_for(blocks * in_c, static_cast<std::size_t>(out_c) * in_c > 4096, [&](long bc) {
    const int b = static_cast<int>(bc / in_c), c = static_cast<int>(bc % in_c);
    for (int k = 0; k < 9; ++k)
      for (int j = 0; j < kCB; ++j) {
        const int o = b * kCB + j;
        float v = 0.f;
        if (o < out_c) {
          v = transpose_flip ? w[(static_cast<std::size_t>(c) * ci + o) * 9 + (8 - k)]
                             : w[(static_cast<std::size_t>(o) * ci + c) * 9 + k];
        }
        dst[((static_cast<std::size_t>(b) * in_c + c) * 9 + k) * kCB + j] = v;
      }
  });
}

// One strip: kCB output channels x kStrip pixels from index q of the padded input planes.
inline void strip_kernel(float* stage, std::size_t stage_stride, const float* pin, std::size_t pstride,
                         const float* wb, int in_c, int ws) {
  __m512 acc[kCB][kNV];
  for (int b = 0; b < kCB; ++b)
    for (int v = 0; v < kNV; ++v) acc[b][v] = _mm512_setzero_ps();
  const std::ptrdiff_t off[9] = {-ws - 1, -ws, -ws + 1, -1, 0, 1, ws - 1, ws, ws + 1};
  for (int c = 0; c < in_c; ++c) {
    const float* p = pin + c * pstride;
    const float* wc = wb + static_cast<std::size_t>(c) * 9 * kCB;
    if (kPrefetch) {  // the next strip's three rows: too many streams for the hardware prefetcher
      for (int r = 0; r < 3; ++r)
        for (int v = 0; v < kNV + 1; ++v)
          _mm_prefetch(reinterpret_cast<const char*>(p + off[3 * r] + kPrefetch + 16 * v), _MM_HINT_T0);
    }
    for (int k = 0; k < 9; ++k) {
      const float* s = p + off[k];
      __m512 x[kNV];
      for (int v = 0; v < kNV; ++v) x[v] = _mm512_loadu_ps(s + 16 * v);
      for (int b = 0; b < kCB; ++b) {
        const __m512 wv = _mm512_set1_ps(wc[k * kCB + b]);
        for (int v = 0; v < kNV; ++v) acc[b][v] = _mm512_fmadd_ps(wv, x[v], acc[b][v]);
      }
    }
  }
  for (int b = 0; b < kCB; ++b)
    for (int v = 0; v < kNV; ++v) _mm512_store_ps(stage + b * stage_stride + 16 * v, acc[b][v]);
}

// out [n, out_c, h, w] = conv of padded planes pin [n][in_c] with packed weights. Each task
// (pixel chunk x output block) stages its tile in L1 and writes it out with bias/ReLU fused.
void conv_padded(const Cat<float>& out, const float* pin, int n, int in_c, const Geom& g, const float* wpack,
                 const float* bias, bool relu) {
  const int out_c = out.channels();
  const int blocks = (out_c + kCB - 1) / kCB;
  const int strips = (g.q_end - g.qa + kStrip - 1) / kStrip;
  const int chunks = (strips + kChunkStrips - 1) / kChunkStrips;
  constexpr int kTile = kStrip * kChunkStrips;
  const double flops = 2.0 * n * (g.q_end - g.q0) * in_c * 9 * out_c;
  const bool par = flops > 2e6;
  const std::size_t oplane = static_cast<std::size_t>(g.h) * g.w;
  parallel_shared(static_cast<long>(n) * chunks * blocks, par, [&](int tid, int nt, Shares& shares) {
    alignas(64) float stage[kCB * kTile];
    shares.run(tid, nt, [&](long tl) {
      const int task = static_cast<int>(tl);
      const int img = task / (chunks * blocks), chunk = (task / blocks) % chunks, b = task % blocks;
      const float* pimg = pin + static_cast<std::size_t>(img) * in_c * g.stride + kFront;
      const float* wb = wpack + static_cast<std::size_t>(b) * in_c * 9 * kCB;
      const int s_begin = chunk * kChunkStrips, s_end = std::min(strips, s_begin + kChunkStrips);
      for (int s = s_begin; s < s_end; ++s)
        strip_kernel(stage + (s - s_begin) * kStrip, kTile, pimg + g.qa + s * kStrip, g.stride, wb, in_c, g.ws);
      // Write out the valid pixels of [qs, qe).
      write_staged_tile([&](int o) { return out.plane(img, o, oplane); }, stage, kTile, b * kCB,
                        std::min(kCB, out_c - b * kCB), bias, relu, g.qa + s_begin * kStrip, g.qa + s_end * kStrip,
                        g.h, g.w, g.ws);
    });
  });
}

// Weight gradient of CB output channels (from o0), input channel c, kernel row kh over the pixel
// range [qa, qb): 3 CB dot products of g rows with the shifted input row.
template <int CB>
void wgrad_task(float* d_weight, const float* gimg, const float* pimg, const Geom& g, int ci, int o0, int c, int kh,
                int qa, int qb) {
  __m512 acc[CB][3];
  for (int b = 0; b < CB; ++b) acc[b][0] = acc[b][1] = acc[b][2] = _mm512_setzero_ps();
  const float* pr = pimg + c * g.stride + kFront + (kh - 1) * g.ws - 1;
  const float* gr = gimg + o0 * g.stride + kFront;
  for (int q = qa; q < qb; q += 16) {
    if (kWgPrefetch) {
      _mm_prefetch(reinterpret_cast<const char*>(pr + q + kWgPrefetch), _MM_HINT_T0);
      for (int b = 0; b < CB; ++b)
        _mm_prefetch(reinterpret_cast<const char*>(gr + b * g.stride + q + kWgPrefetch), _MM_HINT_T0);
    }
    const __m512 x0 = _mm512_loadu_ps(pr + q), x1 = _mm512_loadu_ps(pr + q + 1), x2 = _mm512_loadu_ps(pr + q + 2);
    for (int b = 0; b < CB; ++b) {
      __m512 gv = _mm512_load_ps(gr + b * g.stride + q);
      // Keep gv in a register: folded into each FMA as a memory operand it would be loaded three
      // times, and loads, not FMAs, would bound the kernel.
      asm("" : "+v"(gv));
      acc[b][0] = _mm512_fmadd_ps(gv, x0, acc[b][0]);
      acc[b][1] = _mm512_fmadd_ps(gv, x1, acc[b][1]);
      acc[b][2] = _mm512_fmadd_ps(gv, x2, acc[b][2]);
    }
  }
  for (int b = 0; b < CB; ++b) {
    float* d = d_weight + (static_cast<std::size_t>(o0 + b) * ci + c) * 9 + kh * 3;
    for (int kw = 0; kw < 3; ++kw) d[kw] += hsum(acc[b][kw]);
  }
}

using WgradFn = void (*)(float*, const float*, const float*, const Geom&, int, int, int, int, int, int);
constexpr WgradFn kWgrad[kCB + 1] = {nullptr,        wgrad_task<1>, wgrad_task<2>, wgrad_task<3>, wgrad_task<4>,
                                      wgrad_task<5>, wgrad_task<6>, wgrad_task<7>, wgrad_task<8>};

}  // namespace

void conv3x3_forward(float* out, const float* in, int n, int ci, int h, int w, const float* weight,
                     const float* bias, int co, bool relu, const ConvSettings& cs) {
  conv3x3_forward_cat(out, in, ci, nullptr, 0, n, h, w, weight, bias, co, relu, cs);
}

void conv3x3_forward_cat(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                         const float* weight, const float* bias, int co, bool relu, const ConvSettings& cs) {
  const int ci = ca + cb;
  if (conv_choice(cs, ConvPass::forward, n, ci, co, h, w) == ConvAlgo::winograd) {
    avx512::winograd_conv3x3(OutPlaneSet{out, co}, PlaneSet{a, ca, b, cb}, nullptr, n, h, w, weight, false, bias, relu);
    return;
  }
  const Geom g(h, w);
  float* pin = tl_pad_in.get(g.stride * ci * n);
  const bool par = static_cast<std::size_t>(n) * ci * h * w > (1u << 15);
  pad_planes(pin, Cat<const float>{a, ca, b, cb}, nullptr, n, g, par);
  const std::size_t wp_floats = static_cast<std::size_t>((co + kCB - 1) / kCB) * kCB * ci * 9;
  bool valid = false;
  float* wp = cs.weight_cache ? static_cast<float*>(cs.weight_cache->get(WeightForm::direct, weight,
                                                                          static_cast<std::size_t>(co) * ci * 9, co, ci,
                                                                          wp_floats * sizeof(float), &valid))
                              : tl_wpack.get(wp_floats);
  if (!valid) pack_weights(wp, weight, co, ci, false);
  conv_padded(Cat<float>{out, co}, pin, n, ci, g, wp, bias, relu);
}

void conv3x3_backward(float* d_in, float* d_weight, float* d_bias, const float* d_out, const float* out,
                      const float* in, const float* weight, int n, int ci, int h, int w, int co, bool relu,
                      const ConvSettings& cs) {
  conv3x3_backward_cat(d_in, nullptr, d_weight, d_bias, d_out, out, in, ci, nullptr, 0, weight, n, h, w, co, relu, cs);
}

void conv3x3_backward_cat(float* d_a, float* d_b, float* d_weight, float* d_bias, const float* d_out, const float* out,
                          const float* a, int ca, const float* b, int cb, const float* weight, int n, int h, int w,
                          int co, bool relu, const ConvSettings& cs) {
  const Geom g(h, w);
  const int ci = ca + cb;
  const bool par = static_cast<std::size_t>(n) * co * h * w > (1u << 15);
  // Chosen before any scratch is touched: a calibrating plan runs these kernels itself.
  const bool wino_w = d_weight && conv_choice(cs, ConvPass::weight_grad, n, ci, co, h, w) == ConvAlgo::winograd;
  const bool wino_d = d_a && conv_choice(cs, ConvPass::input_grad, n, ci, co, h, w) == ConvAlgo::winograd;
  // gp: the ReLU-masked output gradient, padded (zeros in the borders: junk pixels add nothing),
  // for the direct kernels; with only Winograd ones the bias needs just its sums (same order),
  // which the by-phase copy for Winograd's weight gradient also gives.
  float* gp = nullptr;
  float* sums = tl_sums.get(static_cast<std::size_t>(co) * n);
  const bool needs_gp = (d_weight && !wino_w) || (d_a && !wino_d);
  float* phase_sums = d_bias && wino_w && !needs_gp ? sums : nullptr;
  if (needs_gp) {
    gp = tl_pad_g.get(g.stride * co * n);
    pad_planes(gp, Cat<const float>{d_out, co}, relu ? out : nullptr, n, g, par, sums);
  } else if (d_bias && !phase_sums) {
    const float* mask = relu ? out : nullptr;
    parallel_for(n * co, par, [&](long ch) {
      const std::size_t off = static_cast<std::size_t>(ch) * h * w;
      sums[ch] = plane_sum(d_out + off, mask ? mask + off : nullptr, w, h, w);
    });
  }

  if (wino_w && wino_d) {  // the masked d_out goes to the by-phase layout once for both
    avx512::winograd_backward(OutPlaneSet{d_a, ca, d_b, cb}, d_weight, PlaneSet{a, ca, b, cb}, d_out, relu ? out : nullptr, n,
                      h, w, weight, co, phase_sums);
  } else if (wino_w) {
    avx512::winograd_weight_grad(d_weight, PlaneSet{a, ca, b, cb}, d_out, relu ? out : nullptr, n, h, w, co, phase_sums);
  }
  if (d_bias) {
    for (int o = 0; o < co; ++o) {
      float acc = 0.f;
      for (int img = 0; img < n; ++img) acc += sums[img * co + o];
      d_bias[o] += acc;
    }
  }

  if (wino_w && wino_d) return;
  if (!wino_w && d_weight) {
    float* pin = tl_pad_in.get(g.stride * ci * n);
    pad_planes(pin, Cat<const float>{a, ca, b, cb}, nullptr, n, g, par);
    const int blocks = (co + kCB - 1) / kCB;
    const int q_stop = g.qa + (g.q_end - g.qa + 15) / 16 * 16;
    const bool wpar = 2.0 * n * (g.q_end - g.q0) * ci * 9 * co > 2e6;
    // Each (output block, input channel, kernel row) task owns its weights and sums its pixel
    // chunks in a fixed order, so the result does not depend on the thread count. Threads take
    // fixed task ranges and walk the chunks in step without barriers: one parallel region.
    // Tasks run input-channel-major when there are at least as many inputs as outputs, else
    // block-major: each thread then reads only its part of the larger of the two operands, and
    // both read all of the smaller.
    const int tasks = blocks * ci * 3;
    const bool c_major = ci >= co;
    parallel(wpar, [&](int tid, int nt) {
      const int t0 = static_cast<int>(static_cast<long>(tasks) * tid / nt);
      const int t1 = static_cast<int>(static_cast<long>(tasks) * (tid + 1) / nt);
      for (int img = 0; img < n; ++img) {
        const float* gimg = gp + static_cast<std::size_t>(img) * co * g.stride;
        const float* pimg = pin + static_cast<std::size_t>(img) * ci * g.stride;
        for (int c0 = g.qa; c0 < q_stop; c0 += kWgChunk) {
          const int c1 = std::min(q_stop, c0 + kWgChunk);
          for (int task = t0; task < t1; ++task) {
            const int b = c_major ? (task / 3) % blocks : task / (ci * 3);
            const int c = c_major ? task / (blocks * 3) : (task / 3) % ci, kh = task % 3;
            const int o0 = b * kCB, cb = std::min(kCB, co - o0);
            kWgrad[cb](d_weight, gimg, pimg, g, ci, o0, c, kh, c0, c1);
          }
        }
      }
    });
  }

  if (wino_d) {
    avx512::winograd_conv3x3(OutPlaneSet{d_a, ca, d_b, cb}, PlaneSet{d_out, co}, relu ? out : nullptr, n, h, w, weight, true,
                     nullptr, false);
  } else if (d_a) {
    float* wp = tl_wpack.get(static_cast<std::size_t>((ci + kCB - 1) / kCB) * kCB * co * 9);
    pack_weights(wp, weight, co, ci, true);
    conv_padded(Cat<float>{d_a, ca, d_b, cb}, gp, n, co, g, wp, nullptr, false);
  }
}

}  // namespace lidarsim::nn::detail::avx512
#include "nn/isa_avx512_end.h"

#endif
