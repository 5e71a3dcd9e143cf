// The convolutions of nn/layers.h: conv2d (im2col + Eigen GEMM, or the hand-written 3x3 kernels
// of nn/conv3x3.h), conv2d over a concatenation without copying it, and the 2x2 transposed
// convolution. The other layers are in nn/layers.cpp.
// GCC 12's AVX-512 intrinsic headers initialise "undefined" vectors from themselves, which its
// own -W(maybe-)uninitialized then reports wherever they are inlined (Eigen's kernels included).
// The pragma must precede the headers: diagnostics are judged at the header's lines.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "nn/layers.h"

#include <algorithm>
#include <string>

#include "common/error.h"
#include "nn/conv3x3.h"
#include "nn/conv3x3_amx.h"
#include "nn/conv3x3_bf16.h"
#include "nn/conv_transpose2x2.h"
#include "nn/kernel_plan.h"
#include "nn/layers_internal.h"
#include "nn/parallel.h"
#include "nn/winograd.h"

namespace lidarsim::nn {

using detail::parallel;
using detail::parallel_for;
using detail::parallel_ranges;
using detail::static_range;
using layers_internal::check_finite_shape;
using layers_internal::ensure;
using layers_internal::fault;
using layers_internal::kParallelElems;
using layers_internal::kParallelFlops;

namespace {

using Mat = Eigen::Map<Eigen::MatrixXf, 0, Eigen::OuterStride<>>;
using CMat = Eigen::Map<const Eigen::MatrixXf, 0, Eigen::OuterStride<>>;
using RowMat = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// Grow-only scratch: steady-state steps allocate nothing.
float* grow(std::vector<float>& v, std::size_t n) {
  if (v.size() < n) v.resize(n);
  return v.data();
}

// Scratch, per thread: im2col tiles (each team thread its own), and the buffers of one op, which
// only the calling thread touches (the workers get the pointers). Pure caches whose contents do
// not outlive the call: models running in several threads at once (one FMU instance per lidar)
// must not share them.
thread_local std::vector<float> tl_col;
thread_local std::vector<float> tl_masked;    // relu-masked d_out
thread_local std::vector<float> tl_wflip;     // flipped, transposed conv weights for the input gradient
thread_local std::vector<float> tl_partials;  // per-thread weight-gradient partials
thread_local std::vector<float> tl_sums;      // per-plane sums of d_out for the bias gradient


constexpr std::size_t kColFloats = 1 << 17;  // one thread's im2col tile: 512 KB, stays in L2

int tile_pixels(int kdim, int hw) {
  int t = static_cast<int>(kColFloats / static_cast<std::size_t>(std::max(kdim, 1)));
  t = std::max(64, t / 16 * 16);
  return std::min(t, hw);
}

// im2col for output pixels [p0, p0 + t) of one image: col is t x (ci k k), column-major, i.e.
// col[kk * t + j] = img[c, y + kh - pad, x + kw - pad] with kk = (c k + kh) k + kw, (y, x) of p0 + j.
void im2col(float* col, const float* img, int ci, int h, int w, int k, int pad, int wo, int p0, int t) {
  int j = 0;
  while (j < t) {
    const int p = p0 + j;
    const int y = p / wo, x0 = p % wo;
    const int len = std::min(t - j, wo - x0);
    for (int c = 0; c < ci; ++c)
      for (int kh = 0; kh < k; ++kh) {
        const int iy = y + kh - pad;
        for (int kw = 0; kw < k; ++kw) {
          float* dst = col + ((static_cast<std::size_t>(c) * k + kh) * k + kw) * t + j;
          if (iy < 0 || iy >= h) {
            std::fill(dst, dst + len, 0.f);
            continue;
          }
          const float* src = img + (static_cast<std::size_t>(c) * h + iy) * w + (kw - pad);
          const int xs = std::clamp(pad - kw, x0, x0 + len);      // first x with ix >= 0
          const int xe = std::clamp(w + pad - kw, x0, x0 + len);  // end of x with ix < w
          std::fill(dst, dst + (xs - x0), 0.f);
          std::copy(src + xs, src + xe, dst + (xs - x0));
          std::fill(dst + (xe - x0), dst + len, 0.f);
        }
      }
    j += len;
  }
}

// The A operand of one pixel tile's GEMM, [kdim x len] with column stride `stride`: the input
// itself for a 1x1 conv without padding (`direct`), else this thread's im2col of the tile.
const float* tile_operand(const float* src, bool direct, int ci, int h, int w, int k, int pad, int wo, int p0,
                          int len, int kdim, Eigen::Index& stride) {
  if (direct) {
    stride = static_cast<Eigen::Index>(h) * w;
    return src + p0;
  }
  float* col = grow(tl_col, static_cast<std::size_t>(kdim) * len);
  im2col(col, src, ci, h, w, k, pad, wo, p0, len);
  stride = len;
  return col;
}

// Forward convolution of n images [ci, h, w] into [co, ho, wo] with wmat the (ci k k) x co
// column-major weight matrix (= a [co, ci, k, k] row-major weight). Tiles of output pixels are
// the parallel tasks; each thread runs its own GEMM.
void conv_core(float* out, const float* in, int n, int ci, int h, int w, const float* wmat, const float* bias,
               int co, int k, int pad, bool relu) {
  const int ho = h + 2 * pad - k + 1, wo = w + 2 * pad - k + 1;
  const int kdim = ci * k * k, hw = ho * wo;
  const bool direct = k == 1 && pad == 0;  // a 1x1 conv reads the input as its own im2col
  const int t = direct ? std::min(hw, 4096) : tile_pixels(kdim, hw);
  const int tiles = (hw + t - 1) / t;
  const std::size_t in_image = static_cast<std::size_t>(ci) * h * w;
  const std::size_t out_image = static_cast<std::size_t>(co) * hw;
  const bool par = 2.0 * n * hw * kdim * co > kParallelFlops;
  parallel_for(n * tiles, par, [&](long tl) {
    const int task = static_cast<int>(tl), img = task / tiles, p0 = (task % tiles) * t, len = std::min(t, hw - p0);
    const float* src = in + img * in_image;
    Eigen::Index a_stride;
    const float* a_ptr = tile_operand(src, direct, ci, h, w, k, pad, wo, p0, len, kdim, a_stride);
    CMat a(a_ptr, len, kdim, Eigen::OuterStride<>(a_stride));  // [len, K]
    CMat b(wmat, kdim, co, Eigen::OuterStride<>(kdim));        // [K, Co]
    Mat c(out + img * out_image + p0, len, co, Eigen::OuterStride<>(hw));  // [len, Co]
    c.noalias() = a * b;
    if (bias || relu) {
      for (int o = 0; o < co; ++o) {
        float* col_o = c.col(o).data();
        const float bo = bias ? bias[o] : 0.f;
        if (relu)
          for (int j = 0; j < len; ++j) col_o[j] = std::max(col_o[j] + bo, 0.f);
        else
          for (int j = 0; j < len; ++j) col_o[j] += bo;
      }
    }
  });
}

// Below AVX-512 (no direct kernel), the 3x3 layers the plan (or the AVX2 rule) gives to Winograd
// take its port (nn/winograd.h); the others stay on im2col + GEMM. The backward pass is one
// choice there (its two gradients share one by-phase copy): weight_grad's, or input_grad's
// when there is no weight gradient.
bool avx2_winograd(int ci, int co, Shape s, const detail::ConvSettings& cs, ConvPass pass) {
  return !detail::conv3x3_available() &&
         detail::conv_choice(cs, pass, s.n, ci, co, s.h, s.w) == ConvAlgo::winograd;
}
ConvPass backward_pass(const float* d_weight) { return d_weight ? ConvPass::weight_grad : ConvPass::input_grad; }

// bf16 inference's forward (cs.bf16): whether a bf16 kernel (AVX-512 BF16 or AMX) takes this conv, and runs it.
bool bf16_forward(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w, const float* weight,
                  const float* bias, int co, bool relu, const detail::ConvSettings& cs) {
  if (!cs.bf16) return false;
  const ConvAlgo algo = detail::conv_choice(cs, ConvPass::bf16_forward, n, ca + cb, co, h, w);
  if (algo == ConvAlgo::amx)
    detail::conv3x3_amx_forward_cat(out, a, ca, b, cb, n, h, w, weight, bias, co, relu, cs.weight_cache);
  else if (algo == ConvAlgo::avx512_bf16)
    detail::conv3x3_bf16_forward_cat(out, a, ca, b, cb, n, h, w, weight, bias, co, relu, cs.weight_cache);
  return algo != ConvAlgo::fp32;
}

}  // namespace

void conv2d_forward(Tensor& out, const Tensor& in, const float* weight, const float* bias, int co, int k, int pad,
                    bool relu, const detail::ConvSettings& cs) {
  check_finite_shape(in, "conv2d_forward", "in");
  const Shape s = in.shape();
  const int ho = s.h + 2 * pad - k + 1, wo = s.w + 2 * pad - k + 1;
  if (k < 1 || pad < 0 || ho < 1 || wo < 1 || co < 1)
    throw Error("conv2d_forward: kernel: k " + std::to_string(k) + ", pad " + std::to_string(pad) +
                " does not fit input " + s.str());
  ensure(out, Shape{s.n, co, ho, wo});
  // UNet::predict in bf16 (nn/precision.h): a bf16 kernel (AVX-512 BF16 or AMX), where it is the faster choice.
  if (k == 3 && pad == 1 && bf16_forward(out.data(), in.data(), s.c, nullptr, 0, s.n, s.h, s.w, weight, bias, co, relu, cs))
    return;
  if (k == 3 && pad == 1 && detail::conv3x3_available()) {
    detail::conv3x3_forward(out.data(), in.data(), s.n, s.c, s.h, s.w, weight, bias, co, relu, cs);
    return;
  }
  if (k == 3 && pad == 1 && avx2_winograd(s.c, co, s, cs, ConvPass::forward)) {
    detail::winograd_conv3x3(detail::OutPlaneSet{out.data(), co}, detail::PlaneSet{in.data(), s.c}, nullptr, s.n, s.h,
                             s.w, weight, false, bias, relu);
    return;
  }
  conv_core(out.data(), in.data(), s.n, s.c, s.h, s.w, weight, bias, co, k, pad, relu);
}

namespace {

// g = d_out masked by the ReLU (d pre-activation), in the scratch tl_masked.
const float* relu_masked(const Tensor& d_out, const Tensor& out) {
  const std::size_t total = d_out.shape().numel();
  float* m = grow(tl_masked, total);
  const float* o = out.data();
  const float* d = d_out.data();
  parallel_ranges(static_cast<long>(total), total > kParallelElems, [&](long b, long e) {
#pragma omp simd
    for (long i = b; i < e; ++i) m[i] = o[i] > 0.f ? d[i] : 0.f;
  });
  return m;
}

// d_bias [co] += the sum of each output plane of g [n, co, hw].
void conv_bias_grad(float* d_bias, const float* g, int n, int co, int hw, bool par) {
  const std::size_t out_image = static_cast<std::size_t>(co) * hw;
  parallel_for(co, par, [&](long o) {
    float acc = 0.f;
    for (int i = 0; i < n; ++i) {
      Eigen::Map<const Eigen::VectorXf> plane(g + i * out_image + static_cast<std::size_t>(o) * hw, hw);
      acc += plane.sum();
    }
    d_bias[o] += acc;
  });
}

// dW [K, Co] += im2col(in)^T [K, len] * g [len, Co], per thread, then summed in thread order.
void conv_weight_grad(float* d_weight, const float* g, const Tensor& in, int co, int k, int pad, int wo, int hw,
                      bool par) {
  const Shape s = in.shape();
  const int n = s.n, ci = s.c, kdim = ci * k * k;
  const std::size_t out_image = static_cast<std::size_t>(co) * hw;
  const bool direct = k == 1 && pad == 0;
  const int t = direct ? std::min(hw, 4096) : tile_pixels(kdim, hw);
  const int tiles = (hw + t - 1) / t;
  const int threads = detail::team_threads();
  const std::size_t wsize = static_cast<std::size_t>(kdim) * co;
  float* parts = grow(tl_partials, wsize * threads);
  std::fill(parts, parts + wsize * threads, 0.f);
  const std::size_t in_image = s.image();
  parallel(par, [&](int tid, int nt) {
    Mat part(parts + wsize * tid, kdim, co, Eigen::OuterStride<>(kdim));
    const auto [t_begin, t_end] = static_range(n * tiles, tid, nt);
    for (int task = static_cast<int>(t_begin); task < t_end; ++task) {
      const int img = task / tiles, p0 = (task % tiles) * t, len = std::min(t, hw - p0);
      const float* src = in.data() + img * in_image;
      Eigen::Index a_stride;
      const float* a_ptr = tile_operand(src, direct, ci, s.h, s.w, k, pad, wo, p0, len, kdim, a_stride);
      CMat a(a_ptr, len, kdim, Eigen::OuterStride<>(a_stride));
      CMat gm(g + img * out_image + p0, len, co, Eigen::OuterStride<>(hw));
      part.noalias() += a.transpose() * gm;
    }
  });
  parallel_ranges(static_cast<long>(wsize), wsize > kParallelElems, [&](long b, long end) {
#pragma omp simd
    for (long e = b; e < end; ++e) {
      float acc = 0.f;
      for (int th = 0; th < threads; ++th) acc += parts[th * wsize + e];
      d_weight[e] += acc;
    }
  });
}

// d_in = conv(g, flipped weights with in/out swapped, padding k - 1 - pad).
void conv_input_grad(Tensor& d_in, const float* g, Shape s, const float* weight, int co, int k, int pad, int ho,
                     int wo) {
  ensure(d_in, s);
  const int ci = s.c, kk = k * k;
  float* wf = grow(tl_wflip, static_cast<std::size_t>(co) * kk * ci);
  // wf as [co k k, ci] column-major: wf[c * (co k k) + (o k + kh) k + kw] = W[o, c, k-1-kh, k-1-kw]
  for (int c = 0; c < ci; ++c)
    for (int o = 0; o < co; ++o)
      for (int kh = 0; kh < k; ++kh)
        for (int kw = 0; kw < k; ++kw)
          wf[static_cast<std::size_t>(c) * co * kk + (o * k + kh) * k + kw] =
              weight[(static_cast<std::size_t>(o) * ci + c) * kk + (k - 1 - kh) * k + (k - 1 - kw)];
  conv_core(d_in.data(), g, s.n, co, ho, wo, wf, nullptr, ci, k, k - 1 - pad, false);
}

// The backward pass on the AVX2 Winograd path: the weight and input gradients share one by-phase
// copy of the masked output gradient, whose plane sums (one order per plane, whatever the thread
// count) give the bias gradient. mask: the forward output when relu, else null.
void winograd_conv_backward(const detail::OutPlaneSet& d_in, float* d_weight, float* d_bias, const Tensor& d_out,
                            const Tensor* mask, const detail::PlaneSet& in, const float* weight) {
  const Shape so = d_out.shape();
  const int n = so.n, co = so.c, h = so.h, w = so.w;
  const float* m = mask ? mask->data() : nullptr;
  float* sums = d_bias && d_weight ? grow(tl_sums, static_cast<std::size_t>(n) * co) : nullptr;
  if (d_weight && d_in.a)
    detail::winograd_backward(d_in, d_weight, in, d_out.data(), m, n, h, w, weight, co, sums);
  else if (d_weight)
    detail::winograd_weight_grad(d_weight, in, d_out.data(), m, n, h, w, co, sums);
  else if (d_in.a)
    detail::winograd_conv3x3(d_in, detail::PlaneSet{d_out.data(), co}, m, n, h, w, weight, true, nullptr, false);
  if (!d_bias) return;
  if (!sums) {
    const std::size_t hw = so.plane();
    conv_bias_grad(d_bias, mask ? relu_masked(d_out, *mask) : d_out.data(), n, co, static_cast<int>(hw),
                   d_out.numel() > kParallelElems);
    return;
  }
  for (int o = 0; o < co; ++o) {
    float acc = 0.f;
    for (int img = 0; img < n; ++img) acc += sums[static_cast<std::size_t>(img) * co + o];
    d_bias[o] += acc;
  }
}

// Test hooks (testhook::Fault): one wrong index in each gradient, so the checks prove they can fail.
void inject_conv2d_faults(Tensor* d_in, float* d_weight, float* d_bias, std::size_t wsize, int co) {
  if (fault(testhook::Fault::conv2d_bias) && d_bias && co > 1) d_bias[1] = d_bias[0];
  if (fault(testhook::Fault::conv2d_weight) && d_weight && wsize > 1) d_weight[wsize - 1] = d_weight[0];
  if (fault(testhook::Fault::conv2d_input) && d_in && d_in->numel() > 1) d_in->data()[1] = d_in->data()[0];
}

}  // namespace

void conv2d_backward(Tensor* d_in, float* d_weight, float* d_bias, const Tensor& d_out, const Tensor& out,
                     const Tensor& in, const float* weight, int k, int pad, bool relu, const detail::ConvSettings& cs) {
  const Shape s = in.shape(), so = d_out.shape();
  const int n = s.n, ci = s.c, co = so.c, ho = so.h, wo = so.w, hw = ho * wo;
  const int kdim = ci * k * k;
  if (so.n != n || ho != s.h + 2 * pad - k + 1 || wo != s.w + 2 * pad - k + 1)
    throw Error("conv2d_backward: d_out: shape " + so.str() + " does not match input " + s.str());
  if (relu && !(out.shape() == so))
    throw Error("conv2d_backward: out: expected shape " + so.str() + ", got " + out.shape().str());

  if (k == 3 && pad == 1 && detail::conv3x3_available()) {
    if (d_in) ensure(*d_in, s);
    detail::conv3x3_backward(d_in ? d_in->data() : nullptr, d_weight, d_bias, d_out.data(), relu ? out.data() : nullptr,
                             in.data(), weight, n, ci, s.h, s.w, co, relu, cs);
    inject_conv2d_faults(d_in, d_weight, d_bias, static_cast<std::size_t>(kdim) * co, co);
    return;
  }
  if (k == 3 && pad == 1 && avx2_winograd(ci, co, s, cs, backward_pass(d_weight))) {
    if (d_in) ensure(*d_in, s);
    winograd_conv_backward(detail::OutPlaneSet{d_in ? d_in->data() : nullptr, ci}, d_weight, d_bias, d_out,
                           relu ? &out : nullptr, detail::PlaneSet{in.data(), ci}, weight);
    inject_conv2d_faults(d_in, d_weight, d_bias, static_cast<std::size_t>(kdim) * co, co);
    return;
  }
  const float* g = relu ? relu_masked(d_out, out) : d_out.data();
  const bool par = 2.0 * n * hw * kdim * co > kParallelFlops;
  if (d_bias) {
    conv_bias_grad(d_bias, g, n, co, hw, par);
    if (fault(testhook::Fault::conv2d_bias) && co > 1) d_bias[1] = d_bias[0];
  }
  if (d_weight) {
    conv_weight_grad(d_weight, g, in, co, k, pad, wo, hw, par);
    const std::size_t wsize = static_cast<std::size_t>(kdim) * co;
    if (fault(testhook::Fault::conv2d_weight) && wsize > 1) d_weight[wsize - 1] = d_weight[0];
  }
  if (d_in) {
    conv_input_grad(*d_in, g, s, weight, co, k, pad, ho, wo);
    if (fault(testhook::Fault::conv2d_input) && d_in->numel() > 1) d_in->data()[1] = d_in->data()[0];
  }
}

namespace {
void check_cat(const Tensor& a, const Tensor& b, const char* op) {
  const Shape sa = a.shape(), sb = b.shape();
  if (sa.n != sb.n || sa.h != sb.h || sa.w != sb.w || a.numel() == 0)
    throw Error(std::string(op) + ": b: shape " + sb.str() + " does not match a " + sa.str());
}
thread_local Tensor tl_cat, tl_dcat;  // the copy-based fallback's buffers (per thread, as above)
}  // namespace

void conv2d_cat_forward(Tensor& out, const Tensor& a, const Tensor& b, const float* weight, const float* bias, int co,
                        bool relu, const detail::ConvSettings& cs) {
  check_cat(a, b, "conv2d_cat_forward");
  const Shape sa = a.shape();
  ensure(out, Shape{sa.n, co, sa.h, sa.w});
  if (bf16_forward(out.data(), a.data(), sa.c, b.data(), b.shape().c, sa.n, sa.h, sa.w, weight, bias, co, relu, cs))
    return;
  const Shape sb = b.shape();
  if (avx2_winograd(sa.c + sb.c, co, sa, cs, ConvPass::forward)) {
    ensure(out, Shape{sa.n, co, sa.h, sa.w});
    detail::winograd_conv3x3(detail::OutPlaneSet{out.data(), co}, detail::PlaneSet{a.data(), sa.c, b.data(), sb.c},
                             nullptr, sa.n, sa.h, sa.w, weight, false, bias, relu);
    return;
  }
  if (!detail::conv3x3_available()) {
    concat_forward(tl_cat, a, b);
    conv2d_forward(out, tl_cat, weight, bias, co, 3, 1, relu, cs);
    return;
  }
  ensure(out, Shape{sa.n, co, sa.h, sa.w});
  detail::conv3x3_forward_cat(out.data(), a.data(), sa.c, b.data(), b.shape().c, sa.n, sa.h, sa.w, weight, bias, co,
                              relu, cs);
}

void conv2d_cat_backward(Tensor& d_a, Tensor& d_b, float* d_weight, float* d_bias, const Tensor& d_out,
                         const Tensor& out, const Tensor& a, const Tensor& b, const float* weight, bool relu,
                         const detail::ConvSettings& cs) {
  check_cat(a, b, "conv2d_cat_backward");
  const Shape sa = a.shape(), sb = b.shape(), so = d_out.shape();
  if (so.n != sa.n || so.h != sa.h || so.w != sa.w || (relu && !(out.shape() == so)))
    throw Error("conv2d_cat_backward: d_out: shape " + so.str() + " does not match input " + sa.str());
  if (avx2_winograd(sa.c + sb.c, so.c, sa, cs, backward_pass(d_weight))) {
    ensure(d_a, sa);
    ensure(d_b, sb);
    winograd_conv_backward(detail::OutPlaneSet{d_a.data(), sa.c, d_b.data(), sb.c}, d_weight, d_bias, d_out,
                           relu ? &out : nullptr, detail::PlaneSet{a.data(), sa.c, b.data(), sb.c}, weight);
    if (fault(testhook::Fault::concat) && d_b.numel() > 1) d_b.data()[1] = d_b.data()[0];
    return;
  }
  if (!detail::conv3x3_available()) {
    concat_forward(tl_cat, a, b);
    conv2d_backward(&tl_dcat, d_weight, d_bias, d_out, out, tl_cat, weight, 3, 1, relu, cs);
    concat_backward(d_a, d_b, tl_dcat, sa.c, false);
    return;
  }
  ensure(d_a, sa);
  ensure(d_b, sb);
  detail::conv3x3_backward_cat(d_a.data(), d_b.data(), d_weight, d_bias, d_out.data(), relu ? out.data() : nullptr,
                               a.data(), sa.c, b.data(), sb.c, weight, sa.n, sa.h, sa.w, so.c, relu, cs);
  if (fault(testhook::Fault::concat) && d_b.numel() > 1) d_b.data()[1] = d_b.data()[0];
}

void conv_transpose2x2_forward(Tensor& out, const Tensor& in, const float* weight, const float* bias, int co,
                               int out_h, int out_w) {
  check_finite_shape(in, "conv_transpose2x2_forward", "in");
  const Shape s = in.shape();
  if (out_h < 2 * s.h || out_w < 2 * s.w)
    throw Error("conv_transpose2x2_forward: out: " + std::to_string(out_h) + " x " + std::to_string(out_w) +
                " is smaller than twice the input " + s.str());
  ensure(out, Shape{s.n, co, out_h, out_w});
  if (detail::conv_transpose2x2_available()) {
    detail::conv_transpose2x2_forward_fast(out.data(), in.data(), s.n, s.c, s.h, s.w, weight, bias, co, out_h, out_w);
    return;
  }
  const int ci = s.c, h = s.h, w = s.w, hw = h * w, co4 = 4 * co;
  // Input rows per task: ~2048 pixels, but at least 4 tasks so deep (short) maps still split.
  const int rows = std::max(1, std::min((h + 3) / 4, 2048 / w));
  const int tiles = (h + rows - 1) / rows;
  const std::size_t oplane = static_cast<std::size_t>(out_h) * out_w;
  Eigen::Map<const RowMat> wm(weight, ci, co4);  // [Ci, Co 2 2]
  const bool par = 2.0 * s.n * hw * ci * co4 > kParallelFlops;
  parallel_for(s.n * tiles, par, [&](long task) {
    const int img = static_cast<int>(task / tiles), y0 = static_cast<int>(task % tiles) * rows, y1 = std::min(h, y0 + rows);
    const int len = (y1 - y0) * w;
    float* y = grow(tl_col, static_cast<std::size_t>(len) * co4);
    CMat x(in.image(img) + y0 * w, len, ci, Eigen::OuterStride<>(hw));  // [len, Ci]
    Mat ym(y, len, co4, Eigen::OuterStride<>(len));                       // [len, Co 2 2]
    ym.noalias() = x * wm;
    float* dst = out.image(img);
    for (int o = 0; o < co; ++o) {
      const float bo = bias ? bias[o] : 0.f;
      float* plane = dst + o * oplane;
      for (int iy = y0; iy < y1; ++iy)
        for (int a = 0; a < 2; ++a) {
          float* row = plane + static_cast<std::size_t>(2 * iy + a) * out_w;
          const float* y_0 = y + static_cast<std::size_t>(o * 4 + a * 2 + 0) * len + (iy - y0) * w;
          const float* y_1 = y + static_cast<std::size_t>(o * 4 + a * 2 + 1) * len + (iy - y0) * w;
          for (int ix = 0; ix < w; ++ix) {
            row[2 * ix] = y_0[ix] + bo;
            row[2 * ix + 1] = y_1[ix] + bo;
          }
          std::fill(row + 2 * w, row + out_w, 0.f);
        }
      if (y1 == h)  // the zero padding below the up-sampled map
        std::fill(plane + static_cast<std::size_t>(2 * h) * out_w, plane + oplane, 0.f);
    }
  });
}

void conv_transpose2x2_backward(Tensor& d_in, float* d_weight, float* d_bias, const Tensor& d_out,
                                const Tensor& in, const float* weight) {
  const Shape s = in.shape(), so = d_out.shape();
  const int n = s.n, ci = s.c, h = s.h, w = s.w, hw = h * w, co = so.c, co4 = 4 * co;
  if (so.n != n || so.h < 2 * h || so.w < 2 * w)
    throw Error("conv_transpose2x2_backward: d_out: shape " + so.str() + " does not match input " + s.str());
  ensure(d_in, s);
  const int out_w = so.w;
  const std::size_t oplane = so.plane();
  const int rows = std::max(1, std::min((h + 3) / 4, 2048 / w));
  const int tiles = (h + rows - 1) / rows;
  const int threads = detail::team_threads();
  const std::size_t wsize = static_cast<std::size_t>(ci) * co4;
  // Per-thread partials: weight gradient, then bias gradient.
  const std::size_t psize = wsize + co;
  float* parts = grow(tl_partials, psize * threads);
  std::fill(parts, parts + psize * threads, 0.f);
  Eigen::Map<const RowMat> wm(weight, ci, co4);
  const bool par = 2.0 * n * hw * ci * co4 > kParallelFlops;
  parallel(par, [&](int tid, int nt) {
    float* part = parts + psize * tid;
    Eigen::Map<RowMat> dw(part, ci, co4);
    float* db = part + wsize;
    const auto [t_begin, t_end] = static_range(n * tiles, tid, nt);
    for (int task = static_cast<int>(t_begin); task < t_end; ++task) {
      const int img = task / tiles, y0 = (task % tiles) * rows, y1 = std::min(h, y0 + rows);
      const int len = (y1 - y0) * w;
      float* gy = grow(tl_col, static_cast<std::size_t>(len) * co4);
      const float* src = d_out.image(img);
      for (int o = 0; o < co; ++o) {
        const float* plane = src + o * oplane;
        float bsum = 0.f;
        for (int iy = y0; iy < y1; ++iy)
          for (int a = 0; a < 2; ++a) {
            const float* row = plane + static_cast<std::size_t>(2 * iy + a) * out_w;
            float* g0 = gy + static_cast<std::size_t>(o * 4 + a * 2 + 0) * len + (iy - y0) * w;
            float* g1 = gy + static_cast<std::size_t>(o * 4 + a * 2 + 1) * len + (iy - y0) * w;
            for (int ix = 0; ix < w; ++ix) {
              g0[ix] = row[2 * ix];
              g1[ix] = row[2 * ix + 1];
              bsum += row[2 * ix] + row[2 * ix + 1];
            }
          }
        db[o] += bsum;
      }
      CMat g(gy, len, co4, Eigen::OuterStride<>(len));                       // [len, Co 2 2]
      CMat x(in.image(img) + y0 * w, len, ci, Eigen::OuterStride<>(hw));      // [len, Ci]
      Mat dx(d_in.image(img) + y0 * w, len, ci, Eigen::OuterStride<>(hw));    // [len, Ci]
      dx.noalias() = g * wm.transpose();
      dw.noalias() += x.transpose() * g;
    }
  });
  parallel_for(static_cast<long>(psize), psize > kParallelElems, [&](long el) {
    const std::size_t e = static_cast<std::size_t>(el);
    float acc = 0.f;
    for (int th = 0; th < threads; ++th) acc += parts[th * psize + e];
    if (e < wsize) {
      if (d_weight) d_weight[e] += acc;
    } else if (d_bias) {
      d_bias[e - wsize] += acc;
    }
  });
  if (fault(testhook::Fault::conv_transpose_weight) && d_weight && wsize > 2) d_weight[2] = d_weight[1];
  if (fault(testhook::Fault::conv_transpose_input) && d_in.numel() > 1) d_in.data()[d_in.numel() - 1] = d_in.data()[0];
}

}  // namespace lidarsim::nn
