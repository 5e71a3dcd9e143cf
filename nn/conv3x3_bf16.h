#pragma once
// bf16 variant of the direct 3x3 convolution's forward pass (nn/conv3x3.h), for inference only
// (nn/precision.h). Inputs and weights are rounded to bf16 (8-bit mantissa), products are summed
// in fp32 by AVX-512 BF16 dot products over pairs of input channels (_mm512_dpbf16_ps): each
// 32-bit lane of a padded plane holds one pixel of channels 2p and 2p+1, each broadcast weight
// the same two channels' tap. Same register blocking as the fp32 kernel (8 output channels x 48
// pixels), so a vector instruction does twice the multiply-adds; bias and ReLU are fused on the
// way out and outputs are fp32. The code is compiled for AVX-512 BF16 by function attributes, so
// builds without -march=native keep it and choose at run time.
#include "nn/conv_settings.h"

namespace lidarsim::nn::detail {

// Whether this build has the kernel and the CPU runs it (AVX-512 F, BW and BF16), and LIDARSIM_ISA
// allows it (nn/cpu_features.h).
bool conv3x3_bf16_available();

// The contract of conv3x3_forward_cat: out [n, co, h, w] = conv([a (ca channels), b (cb)]) with
// weight [co, ca + cb, 3, 3], plus bias [co] (or null), then ReLU when relu. b may be null (cb 0).
// The packed weights come from `cache` when given (kept across calls), else are packed per call.
void conv3x3_bf16_forward_cat(float* out, const float* a, int ca, const float* b, int cb, int n, int h, int w,
                              const float* weight, const float* bias, int co, bool relu, WeightCache* cache = nullptr);

// Whether a conv of ci -> co channels on n images of h x w takes the bf16 kernel under bf16
// inference (else the fp32 rule of conv3x3_takes_winograd under `path`); with AMX every layer
// (nn/conv3x3_amx.h) unless `path` forces Winograd.
bool conv3x3_takes_bf16(int n, int ci, int co, int h, int w, Conv3x3Path path = conv3x3_path());

}  // namespace lidarsim::nn::detail
