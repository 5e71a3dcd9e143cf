#pragma once
// Winograd F(4x4, 3x3) convolution (stride 1, padding 1): each 4 x 4 output tile costs 36
// products per channel pair instead of 144. Input tiles (6 x 6) and weights go to the
// transform domain, 36 independent channel GEMMs run there, and the output transform adds the
// bias and the ReLU on the way out. Tiles sit in the AVX-512 lanes (16 horizontally adjacent
// tiles of one tile row per vector), so the transforms are plain vector adds.
// Its error against the direct kernel is measured in tests/nn/test_winograd.cpp.
#include <cstddef>

namespace lidarsim::nn::detail {

// Whether a Winograd path runs at the active level (nn/cpu_features.h): the AVX-512 kernels
// (namespace avx512, AVX-512 code: nn/isa_avx512_begin.h) or their AVX2 ports (namespace avx2,
// nn/winograd_avx2.h: the build's baseline, on every CPU). The functions at the end of this
// header call the active level's.
bool winograd_available();

// NCHW planes [n][ca + cb] split over two buffers (the UNet's concat without a copy).
struct PlaneSet {
  const float* a;
  int ca;
  const float* b = nullptr;
  int cb = 0;
};
struct OutPlaneSet {
  float* a;
  int ca;
  float* b = nullptr;
  int cb = 0;
};

namespace avx512 {

// out = conv3x3(in) with weight [co, ci, 3, 3] (out has co channels, in ci), plus bias [co] (or
// null), then ReLU when relu. With transpose_flip the weight is [ci, co, 3, 3] read flipped (the
// input gradient of a conv whose output has ci channels). With mask, in counts only where
// mask > 0 (the ReLU backward: mask is the forward output, same layout as in).
void winograd_conv3x3(const OutPlaneSet& out, const PlaneSet& in, const float* mask, int n, int h, int w,
                      const float* weight, bool transpose_flip, const float* bias, bool relu);

// Both gradients of that conv at once: adds the weight gradient to d_weight (winograd_weight_grad)
// and writes the input gradient to d_in (winograd_conv3x3 with transpose_flip, weight
// [co, ci, 3, 3]), bringing the masked d_out into the by-phase layout once for both. sums as in
// winograd_weight_grad.
void winograd_backward(const OutPlaneSet& d_in, float* d_weight, const PlaneSet& in, const float* d_out,
                       const float* mask, int n, int h, int w, const float* weight, int co, float* sums = nullptr);

// The transformed weights U = G k G^T that winograd_conv3x3 multiplies with, for tests: packed
// [36 transform elements][ceil(co / 8)][ci][8 output channels] (zeros past the last one), the
// elements winograd_u_stride(co, ci) floats apart; u is 64-byte aligned.
std::size_t winograd_u_stride(int co, int ci);
void winograd_transform_weights(float* u, const float* weight, int co, int ci, bool transpose_flip);

// Adds the weight gradient of that conv (no flip) to d_weight [co, ci, 3, 3]: d_out [n, co, h, w]
// (masked where mask > 0 when mask is given) against in [n, ci, h, w], through the transposed
// algorithm: the transformed output gradient (A dY A^T) times the transformed input tiles
// (B^T d B), summed over all tiles per transform element, then G^T (.) G. The tile sums run in
// a fixed order, so the result does not depend on the thread count. With sums, sums[img co + o]
// also gets the sum of each (masked) d_out plane in the bias gradient's plain order (each row
// from x = 0 up, the rows from y = 0 down), read in the same pass.
void winograd_weight_grad(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n, int h,
                          int w, int co, float* sums = nullptr);

}  // namespace avx512
// The AVX2 ports (8-lane vectors, the same layouts and summation plan; their own bits).
namespace avx2 {
void winograd_conv3x3(const OutPlaneSet& out, const PlaneSet& in, const float* mask, int n, int h, int w,
                      const float* weight, bool transpose_flip, const float* bias, bool relu);
void winograd_backward(const OutPlaneSet& d_in, float* d_weight, const PlaneSet& in, const float* d_out,
                       const float* mask, int n, int h, int w, const float* weight, int co, float* sums = nullptr);
std::size_t winograd_u_stride(int co, int ci);
void winograd_transform_weights(float* u, const float* weight, int co, int ci, bool transpose_flip);
void winograd_weight_grad(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n, int h,
                          int w, int co, float* sums = nullptr);
}  // namespace avx2

// The active level's kernels (AVX-512 where active_isa() allows it, else AVX2); call only when
// winograd_available(). Called from inside namespace avx512, write avx512::winograd_... (the
// arguments' namespace would make a plain call ambiguous).
void winograd_conv3x3(const OutPlaneSet& out, const PlaneSet& in, const float* mask, int n, int h, int w,
                      const float* weight, bool transpose_flip, const float* bias, bool relu);
void winograd_backward(const OutPlaneSet& d_in, float* d_weight, const PlaneSet& in, const float* d_out,
                       const float* mask, int n, int h, int w, const float* weight, int co, float* sums = nullptr);
std::size_t winograd_u_stride(int co, int ci);
void winograd_transform_weights(float* u, const float* weight, int co, int ci, bool transpose_flip);
void winograd_weight_grad(float* d_weight, const PlaneSet& in, const float* d_out, const float* mask, int n, int h,
                          int w, int co, float* sums = nullptr);

}  // namespace lidarsim::nn::detail
