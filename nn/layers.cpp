// The layers of nn/layers.h other than the convolutions (nn/conv_layers.cpp): max pooling, ReLU,
// concatenation, the per-row affine map and the lookup base. GCC 12's AVX-512 intrinsic headers
// trip -W(maybe-)uninitialized wherever they are inlined; the pragma must precede the headers.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/layers.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "common/error.h"
#include "nn/cpu_features.h"
#include "nn/layers_internal.h"
#include "nn/parallel.h"

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>

#include "nn/isa_avx512_begin.h"
namespace lidarsim::nn::detail::avx512 {
// Max pooling of one output row, 16 windows at a time, while 16 fit (input rows r0, r1, w wide;
// output row y, wo wide): even/odd columns split, then the scalar loop's ordered comparisons, so
// values and argmax are the scalar ones. Returns the first column left to the scalar loop.
int max_pool2x2_row(float* dst, std::int32_t* am, const float* r0, const float* r1, int wo, int y, int w) {
  const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
  const __m512i odd = _mm512_add_epi32(even, _mm512_set1_epi32(1));
  int x = 0;
  for (; x + 16 <= wo; x += 16) {
    const __m512 a0 = _mm512_loadu_ps(r0 + 2 * x), a1 = _mm512_loadu_ps(r0 + 2 * x + 16);
    const __m512 b0 = _mm512_loadu_ps(r1 + 2 * x), b1 = _mm512_loadu_ps(r1 + 2 * x + 16);
    __m512 v = _mm512_permutex2var_ps(a0, even, a1);
    __m512i idx = _mm512_add_epi32(_mm512_set1_epi32(2 * y * w + 2 * x), even);
    const __m512 c1 = _mm512_permutex2var_ps(a0, odd, a1);
    const __m512 c2 = _mm512_permutex2var_ps(b0, even, b1);
    const __m512 c3 = _mm512_permutex2var_ps(b0, odd, b1);
    __mmask16 m = _mm512_cmp_ps_mask(c1, v, _CMP_GT_OQ);
    v = _mm512_mask_blend_ps(m, v, c1);
    idx = _mm512_mask_add_epi32(idx, m, idx, _mm512_set1_epi32(1));
    m = _mm512_cmp_ps_mask(c2, v, _CMP_GT_OQ);
    v = _mm512_mask_blend_ps(m, v, c2);
    const __m512i i2 = _mm512_add_epi32(_mm512_set1_epi32((2 * y + 1) * w + 2 * x), even);
    idx = _mm512_mask_blend_epi32(m, idx, i2);
    m = _mm512_cmp_ps_mask(c3, v, _CMP_GT_OQ);
    v = _mm512_mask_blend_ps(m, v, c3);
    idx = _mm512_mask_blend_epi32(m, idx, _mm512_add_epi32(i2, _mm512_set1_epi32(1)));
    _mm512_storeu_ps(dst + x, v);
    _mm512_storeu_si512(am + x, idx);
  }
  return x;
}
}  // namespace lidarsim::nn::detail::avx512
#include "nn/isa_avx512_end.h"
#else
namespace lidarsim::nn::detail::avx512 {
inline int max_pool2x2_row(float*, std::int32_t*, const float*, const float*, int, int, int) { return 0; }
}  // namespace lidarsim::nn::detail::avx512
#endif

namespace lidarsim::nn {

using detail::parallel_for;
using detail::parallel_ranges;
using layers_internal::check_finite_shape;
using layers_internal::ensure;
using layers_internal::fault;
using layers_internal::kParallelElems;

namespace testhook {
Fault fault = Fault::none;
}  // namespace testhook

void max_pool2x2_forward(Tensor& out, std::vector<std::int32_t>& argmax, const Tensor& in) {
  check_finite_shape(in, "max_pool2x2_forward", "in");
  const Shape s = in.shape();
  const int ho = s.h / 2, wo = s.w / 2;
  if (ho < 1 || wo < 1) throw Error("max_pool2x2_forward: in: expected at least 2 x 2, got " + s.str());
  ensure(out, Shape{s.n, s.c, ho, wo});
  if (argmax.size() != out.numel()) argmax.resize(out.numel());
  const int planes = s.n * s.c;
  const bool wide = isa_at_least(Isa::avx512);
  parallel_for(planes, in.numel() > kParallelElems, [&](long p) {
    const float* src = in.data() + p * s.plane();
    float* dst = out.data() + p * out.shape().plane();
    std::int32_t* am = argmax.data() + p * out.shape().plane();
    for (int y = 0; y < ho; ++y) {
      const float* r0 = src + static_cast<std::size_t>(2 * y) * s.w;
      const float* r1 = r0 + s.w;
      int x = 0;
      if (wide) x = detail::avx512::max_pool2x2_row(dst + y * wo, am + y * wo, r0, r1, wo, y, s.w);
      for (; x < wo; ++x) {
        // Row order, first wins on ties (NaN never wins: comparisons with NaN are false).
        int best = 2 * y * s.w + 2 * x;
        float v = r0[2 * x];
        if (r0[2 * x + 1] > v) v = r0[2 * x + 1], best = 2 * y * s.w + 2 * x + 1;
        if (r1[2 * x] > v) v = r1[2 * x], best = (2 * y + 1) * s.w + 2 * x;
        if (r1[2 * x + 1] > v) v = r1[2 * x + 1], best = (2 * y + 1) * s.w + 2 * x + 1;
        dst[y * wo + x] = v;
        am[y * wo + x] = best;
      }
    }
  });
}

void max_pool2x2_backward(Tensor& d_in, const Tensor& d_out, const std::vector<std::int32_t>& argmax,
                          Shape in_shape, bool accumulate) {
  const Shape so = d_out.shape();
  if (argmax.size() != d_out.numel() || in_shape.n != so.n || in_shape.c != so.c || in_shape.h / 2 != so.h ||
      in_shape.w / 2 != so.w)
    throw Error("max_pool2x2_backward: d_out: shape " + so.str() + " does not match input " + in_shape.str());
  if (accumulate) {
    if (!(d_in.shape() == in_shape))
      throw Error("max_pool2x2_backward: d_in: expected shape " + in_shape.str() + ", got " + d_in.shape().str());
  } else {
    ensure(d_in, in_shape);
  }
  const int planes = so.n * so.c;
  const std::size_t ip = in_shape.plane(), op = so.plane();
  const bool broken = fault(testhook::Fault::max_pool);
  parallel_for(planes, d_out.numel() > kParallelElems / 4, [&](long p) {
    float* dst = d_in.data() + p * ip;
    if (!accumulate) std::fill(dst, dst + ip, 0.f);
    const float* src = d_out.data() + p * op;
    const std::int32_t* am = argmax.data() + p * op;
    for (std::size_t i = 0; i < op; ++i) dst[am[i]] += src[i];
    if (broken && p == 0 && op > 0) {  // route the first window's gradient to a neighbour
      dst[am[0]] -= src[0];
      dst[am[0] ^ 1] += src[0];
    }
  });
}

void max_pool2x2_backward(Tensor& d_in, const Tensor& d_out, const std::vector<std::int32_t>& argmax) {
  const Shape so = d_out.shape();
  max_pool2x2_backward(d_in, d_out, argmax, Shape{so.n, so.c, 2 * so.h, 2 * so.w}, false);
}

void relu_forward(Tensor& out, const Tensor& in) {
  ensure(out, in.shape());
  const std::size_t n = in.numel();
  const float* x = in.data();
  float* y = out.data();
  parallel_ranges(static_cast<long>(n), n > kParallelElems, [&](long b, long e) {
#pragma omp simd
    for (long i = b; i < e; ++i) y[i] = std::max(x[i], 0.f);
  });
}

void relu_backward(Tensor& d_in, const Tensor& d_out, const Tensor& out) {
  if (!(d_out.shape() == out.shape()))
    throw Error("relu_backward: d_out: expected shape " + out.shape().str() + ", got " + d_out.shape().str());
  ensure(d_in, out.shape());
  const std::size_t n = out.numel();
  const float* d = d_out.data();
  const float* y = out.data();
  float* dx = d_in.data();
  parallel_ranges(static_cast<long>(n), n > kParallelElems, [&](long b, long e) {
#pragma omp simd
    for (long i = b; i < e; ++i) dx[i] = y[i] > 0.f ? d[i] : 0.f;
  });
  if (fault(testhook::Fault::relu) && n > 1) dx[1] = d[0];
}

void concat_forward(Tensor& out, const Tensor& a, const Tensor& b) {
  const Shape sa = a.shape(), sb = b.shape();
  if (sa.n != sb.n || sa.h != sb.h || sa.w != sb.w)
    throw Error("concat_forward: b: shape " + sb.str() + " does not match a " + sa.str());
  ensure(out, Shape{sa.n, sa.c + sb.c, sa.h, sa.w});
  const int ct = sa.c + sb.c;
  const std::size_t plane = sa.plane();
  parallel_for(sa.n * ct, out.numel() > kParallelElems, [&](long p) {
    const int i = static_cast<int>(p / ct), c = static_cast<int>(p % ct);
    const float* src = c < sa.c ? a.channel(i, c) : b.channel(i, c - sa.c);
    std::copy(src, src + plane, out.channel(i, c));
  });
}

void concat_backward(Tensor& d_a, Tensor& d_b, const Tensor& d_out, int ca, bool accumulate_a) {
  const Shape s = d_out.shape();
  if (ca < 0 || ca > s.c) throw Error("concat_backward: ca: " + std::to_string(ca) + " outside " + s.str());
  const Shape sa{s.n, ca, s.h, s.w}, sb{s.n, s.c - ca, s.h, s.w};
  if (accumulate_a) {
    if (!(d_a.shape() == sa))
      throw Error("concat_backward: d_a: expected shape " + sa.str() + ", got " + d_a.shape().str());
  } else {
    ensure(d_a, sa);
  }
  ensure(d_b, sb);
  const std::size_t plane = s.plane();
  parallel_for(s.n * s.c, d_out.numel() > kParallelElems, [&](long p) {
    const int i = static_cast<int>(p / s.c), c = static_cast<int>(p % s.c);
    const float* src = d_out.channel(i, c);
    if (c >= ca) {
      std::copy(src, src + plane, d_b.channel(i, c - ca));
    } else if (accumulate_a) {
      float* dst = d_a.channel(i, c);
      for (std::size_t j = 0; j < plane; ++j) dst[j] += src[j];
    } else {
      std::copy(src, src + plane, d_a.channel(i, c));
    }
  });
  if (fault(testhook::Fault::concat) && d_b.numel() > 1) d_b.data()[1] = d_b.data()[0];
}

void concat_backward(Tensor& d_a, Tensor& d_b, const Tensor& d_out) {
  concat_backward(d_a, d_b, d_out, d_a.shape().c, false);
}

void row_affine_forward(Tensor& out, const Tensor& in, const float* gain, const float* offset) {
  check_finite_shape(in, "row_affine_forward", "in");
  const Shape s = in.shape();
  ensure(out, s);
  const int rows = s.n * s.c * s.h;
  parallel_for(rows, true, [&](long r) {
    const int ch = static_cast<int>(r % (s.c * s.h));  // channel * H + row
    const float a = gain[ch], b = offset[ch];
    const float* x = in.data() + static_cast<std::size_t>(r) * s.w;
    float* y = out.data() + static_cast<std::size_t>(r) * s.w;
    for (int w = 0; w < s.w; ++w) y[w] = a * x[w] + b;
  });
}

void row_affine_backward(Tensor& d_in, float* d_gain, float* d_offset, const Tensor& d_out, const Tensor& in,
                         const float* gain) {
  const Shape s = in.shape();
  if (!(d_out.shape() == s))
    throw Error("row_affine_backward: d_out: shape " + d_out.shape().str() + " does not match input " + s.str());
  ensure(d_in, s);
  const int per_image = s.c * s.h;
  // One (channel, row) per iteration, summed over the batch and the columns in a fixed order.
  parallel_for(per_image, true, [&](long ch) {
    double sg = 0, so = 0;
    for (int n = 0; n < s.n; ++n) {
      const std::size_t base = (static_cast<std::size_t>(n) * per_image + ch) * s.w;
      const float* x = in.data() + base;
      const float* g = d_out.data() + base;
      float* dx = d_in.data() + base;
      for (int w = 0; w < s.w; ++w) {
        sg += static_cast<double>(g[w]) * x[w];
        so += g[w];
        dx[w] = gain[ch] * g[w];
      }
    }
    d_gain[ch] += static_cast<float>(sg);
    d_offset[ch] += static_cast<float>(so);
  });
  if (fault(testhook::Fault::row_affine) && per_image > 1) d_gain[1] = d_gain[0];
}

void lookup_base_keys(std::vector<std::int32_t>& keys, const Tensor& x, const LookupBaseConfig& c) {
  const Shape s = x.shape();
  if (c.classes < 1 || c.range_bins < 1 || !(c.bin_width > 0) || c.class_channel < 0 || c.range_channel < 0 ||
      c.class_channel + c.classes > s.c || c.range_channel >= s.c || s.h != c.rows)
    throw Error("lookup_base: input shape " + s.str() + " does not fit the table (" + std::to_string(c.classes) +
                " class channels from " + std::to_string(c.class_channel) + ", range channel " +
                std::to_string(c.range_channel) + ", " + std::to_string(c.rows) + " rows)");
  const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
  keys.resize(static_cast<std::size_t>(s.n) * plane);
  parallel_for(s.n, true, [&](long nl) {
    const int n = static_cast<int>(nl);
    const float* range = x.channel(n, c.range_channel);
    for (std::size_t i = 0; i < plane; ++i) {
      std::int32_t& k = keys[static_cast<std::size_t>(n) * plane + i];
      if (!(range[i] > 0)) {
        k = -1;
        continue;
      }
      int g = c.classes;
      for (int j = 0; j < c.classes; ++j)
        if (x.channel(n, c.class_channel + j)[i] > 0.5f) {
          g = j;
          break;
        }
      const int b = std::clamp(static_cast<int>(std::floor(range[i] / c.bin_width)), 0, c.range_bins - 1);
      k = g * c.range_bins + b;
    }
  });
}

void lookup_base_forward(Tensor& out, const Tensor& x, const LookupBaseConfig& c, const float* table,
                         const float* beam) {
  // A local buffer: a thread_local one would be a different (empty) vector in each OpenMP worker.
  std::vector<std::int32_t> keys;
  lookup_base_keys(keys, x, c);
  const Shape s = x.shape();
  ensure(out, Shape{s.n, 1, s.h, s.w});
  const std::size_t cells = keys.size();
  parallel_ranges(static_cast<long>(cells), true, [&](long b, long e) {
    for (long i = b; i < e; ++i) {
      const int h = static_cast<int>(i / s.w % s.h);
      out.data()[i] = keys[i] < 0 ? 0.f : table[keys[i]] + beam[h];
    }
  });
}

void lookup_base_backward(float* d_table, float* d_beam, const Tensor& d_out, const Tensor& x,
                          const LookupBaseConfig& c) {
  const Shape s = x.shape();
  if (!(d_out.shape() == Shape{s.n, 1, s.h, s.w}))
    throw Error("lookup_base_backward: d_out: shape " + d_out.shape().str() + " does not match input " + s.str());
  std::vector<std::int32_t> keys;
  lookup_base_keys(keys, x, c);
  // Serial: a cell's key is data, so parallel sums would race; the table is fitted, not trained,
  // so this runs only in checks.
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (keys[i] < 0) continue;
    d_table[keys[i]] += d_out.data()[i];
    d_beam[i / s.w % s.h] += d_out.data()[i];
  }
  if (fault(testhook::Fault::lookup_base) && c.rows > 1) d_beam[1] = d_beam[0];
}

}  // namespace lidarsim::nn
