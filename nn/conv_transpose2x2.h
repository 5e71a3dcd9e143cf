#pragma once
// The AVX-512 forward pass of the 2x2 stride-2 transposed convolution (nn/layers.h has the
// contract). No overlap: output pixel (2y + a, 2x + b) takes input pixel (y, x) times weight tap
// (a, b) only, so the pass is four 1x1 convolutions whose outputs interleave. The kernel keeps
// them in registers and interleaves with permutes: 1.4x less time than a GEMM into a buffer and a
// scalar scatter (bench_up_pool). The backward pass stays two GEMMs: a vectorised de-interleave
// of the output gradient did not change its time, the GEMMs are the cost.

namespace lidarsim::nn::detail {

// Whether the CPU runs the kernel (AVX-512, nn/cpu_features.h); it is AVX-512 code
// (nn/isa_avx512_begin.h), to be called only then.
bool conv_transpose2x2_available();

namespace avx512 {
// in [n, ci, h, w], weight [ci, co, 2, 2], bias [co] or null -> out [n, co, out_h, out_w]
// (out_h >= 2h, out_w >= 2w; the rows and columns past 2h, 2w are zero).
void conv_transpose2x2_forward_fast(float* out, const float* in, int n, int ci, int h, int w, const float* weight,
                                    const float* bias, int co, int out_h, int out_w);
}  // namespace avx512
using avx512::conv_transpose2x2_forward_fast;

}  // namespace lidarsim::nn::detail
