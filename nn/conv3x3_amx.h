#pragma once
// AMX variant of the bf16 forward 3x3 convolution (nn/conv3x3_bf16.h), for inference only: the
// same contract, the same rounding of inputs and weights to bf16 (round to nearest even), fp32
// sums, but as an implicit GEMM on the AMX tiles (_tile_dpbf16ps: 16 pixels x 16 output channels
// per tile, 32 input values per step). The input is staged as zero-padded pixel-major bf16
// (channels padded to 32, or 4-16 for narrow layers), so a tile of 16 pixels x 32 values is one
// strided tile load at any tap offset: whole before the products for small images, per band of
// rows by the task that computes it for large ones. Weights are packed once into the tiles' pair
// layout (kept in the model's WeightCache). Runs only at Isa::amx_bf16 (nn/cpu_features.h).
#include "nn/conv_settings.h"

namespace lidarsim::nn::detail {

// Whether this build has the kernel and the CPU runs it, and LIDARSIM_ISA allows it.
bool conv3x3_amx_available();

// The contract of conv3x3_bf16_forward_cat: out [n, co, h, w] = conv([a (ca channels), b (cb)])
// with weight [co, ca + cb, 3, 3], plus bias [co] (or null), then ReLU when relu; b may be null
// (cb 0). The result bits do not depend on the number of threads.
void conv3x3_amx_forward_cat(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                             const float* weight, const float* bias, int co, bool relu, WeightCache* cache = nullptr);

// Whether a layer that bf16 inference takes (conv3x3_takes_bf16) runs on AMX rather than the
// AVX-512 BF16 kernel (false when AMX is not available).
bool conv3x3_takes_amx(int n, int ci, int co, int h, int w);

// bf16 inference's 3x3 forward pass: the AMX kernel where conv3x3_takes_amx, else the AVX-512
// BF16 kernel.
void conv3x3_bf16_dispatch(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                           const float* weight, const float* bias, int co, bool relu, WeightCache* cache);

}  // namespace lidarsim::nn::detail
