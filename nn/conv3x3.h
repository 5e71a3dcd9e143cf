#pragma once
// Direct 3x3 convolution (stride 1, padding 1) with AVX-512 register blocking: the UNet's hot
// path. Inputs are copied into zero-bordered planes whose rows are w + 2 wide, so every output
// pixel (and every junk pixel in the border columns, computed and then dropped) reads its 3x3
// window at fixed offsets: the kernel is a flat loop over pixels with no boundary tests.
// layers.cpp falls back to im2col + GEMM for other kernels or where the CPU (or LIDARSIM_ISA,
// nn/cpu_features.h) rules AVX-512 out.
#include "nn/conv_settings.h"

namespace lidarsim::nn::detail {

bool conv3x3_available();

// Whether a conv with ci inputs and co outputs takes Winograd under `path`, in all its passes
// (its input gradient is the conv co -> ci).
bool conv3x3_takes_winograd(int ci, int co, Conv3x3Path path = conv3x3_path());

// The rule below AVX-512, where the other choice is im2col + GEMM (no direct kernel): whether a
// conv with ci inputs and co outputs on n maps of h x w takes the AVX2 Winograd port in all its
// passes.
bool conv3x3_avx2_takes_winograd(int ci, int co, int n, int h, int w, Conv3x3Path path = conv3x3_path());

// The kernels below are AVX-512 code (nn/isa_avx512_begin.h): call them only when
// conv3x3_available(). `cs` gives the algorithm and, for the forward pass, the cache of packed
// weights (nn/conv_settings.h).
namespace avx512 {

// in [n, ci, h, w], weight [co, ci, 3, 3], bias [co] or null -> out [n, co, h, w].
void conv3x3_forward(float* out, const float* in, int n, int ci, int h, int w, const float* weight,
                     const float* bias, int co, bool relu, const ConvSettings& cs = {});

// d_out, out [n, co, h, w] (out used for the ReLU mask when relu); writes d_in (may be null),
// adds to d_weight [co, ci, 3, 3] and d_bias [co] (may be null). The weight gradient is summed
// in an order that does not depend on the thread count.
void conv3x3_backward(float* d_in, float* d_weight, float* d_bias, const float* d_out, const float* out,
                      const float* in, const float* weight, int n, int ci, int h, int w, int co, bool relu,
                      const ConvSettings& cs = {});

// The same over the channel concatenation [a (ca channels), b (cb)] without copying it; the
// input gradient is split the same way into d_a, d_b (d_b is needed when d_a is given).
void conv3x3_forward_cat(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                         const float* weight, const float* bias, int co, bool relu, const ConvSettings& cs = {});
void conv3x3_backward_cat(float* d_a, float* d_b, float* d_weight, float* d_bias, const float* d_out, const float* out,
                          const float* a, int ca, const float* b, int cb, const float* weight, int n, int h, int w,
                          int co, bool relu, const ConvSettings& cs = {});
}  // namespace avx512
using avx512::conv3x3_backward;
using avx512::conv3x3_backward_cat;
using avx512::conv3x3_forward;
using avx512::conv3x3_forward_cat;

}  // namespace lidarsim::nn::detail
