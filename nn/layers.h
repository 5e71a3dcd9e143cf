#pragma once
// Layer ops in the style of llm.c: each a forward/backward pair over NCHW buffers.
// Backward writes (=) input gradients (or adds, where a flag says so) and accumulates (+=)
// parameter gradients. Shapes in comments: N batch, C/Ci/Co channels, H/W height/width.
// Output tensors are reshaped when their shape differs (that allocates only when they grow).
// Parallel with OpenMP; reductions over pixels go through per-thread partials summed in thread
// order, so a fixed thread count gives bit-identical results. The ops keep grow-only scratch
// buffers per calling thread (no allocation in steady state; parallelism lives inside each op),
// so several threads may run ops at once on their own tensors.
// 3x3/padding-1 convolutions take a direct AVX-512 kernel (nn/conv3x3.h) when compiled for it;
// everything else goes through im2col + Eigen GEMM. The conv ops take the caller's settings
// (nn/conv_settings.h: algorithm, bf16 forward, packed-weight cache), which a model owns; the
// default is the process default algorithm in fp32.
#include <cstdint>
#include <vector>

#include "nn/conv_settings.h"
#include "nn/tensor.h"

namespace lidarsim::nn {

// conv2d, stride 1, zero padding `pad`, square kernel k (odd k with pad = k/2 keeps H, W).
//   in [N, Ci, H, W], weight [Co, Ci, k, k], bias [Co] (may be null) -> out [N, Co, Ho, Wo],
//   Ho = H + 2 pad - k + 1. `relu` fuses a ReLU after the bias.
void conv2d_forward(Tensor& out, const Tensor& in, const float* weight, const float* bias, int co, int k, int pad,
                    bool relu, const detail::ConvSettings& cs = {});
// d_out is the gradient w.r.t. the (post-ReLU when relu) output; `out` is the forward output
// (used for the ReLU mask). d_in may be null (first layer); d_bias may be null.
void conv2d_backward(Tensor* d_in, float* d_weight, float* d_bias, const Tensor& d_out, const Tensor& out,
                     const Tensor& in, const float* weight, int k, int pad, bool relu,
                     const detail::ConvSettings& cs = {});

// conv2d (3x3, padding 1) over the channel concat [a, b] without materialising it (the UNet's
// decoder input). a [N, Ca, H, W], b [N, Cb, H, W], weight [Co, Ca + Cb, 3, 3].
void conv2d_cat_forward(Tensor& out, const Tensor& a, const Tensor& b, const float* weight, const float* bias, int co,
                        bool relu, const detail::ConvSettings& cs = {});
// Writes the input gradient split as d_a, d_b.
void conv2d_cat_backward(Tensor& d_a, Tensor& d_b, float* d_weight, float* d_bias, const Tensor& d_out,
                         const Tensor& out, const Tensor& a, const Tensor& b, const float* weight, bool relu,
                         const detail::ConvSettings& cs = {});

// Transposed conv 2x2, stride 2 (no overlap): in [N, Ci, H, W], weight [Ci, Co, 2, 2], bias [Co]
//   -> out [N, Co, out_h, out_w] with out_h >= 2H, out_w >= 2W (extra rows/cols are zero: the
//   UNet's pad-to-skip; they carry no bias and pass no gradient).
void conv_transpose2x2_forward(Tensor& out, const Tensor& in, const float* weight, const float* bias, int co,
                               int out_h, int out_w);
void conv_transpose2x2_backward(Tensor& d_in, float* d_weight, float* d_bias, const Tensor& d_out,
                                const Tensor& in, const float* weight);

// Max-pool 2x2 stride 2 (floor): in [N, C, H, W] -> out [N, C, H/2, W/2]; argmax [N, C, H/2, W/2]
// holds the flat index within the input plane. Ties go to the first element in row order.
void max_pool2x2_forward(Tensor& out, std::vector<std::int32_t>& argmax, const Tensor& in);
// d_in gets the input shape from `in_shape`; with accumulate the gradient is added to d_in
// (which must already have that shape) instead of overwriting it.
void max_pool2x2_backward(Tensor& d_in, const Tensor& d_out, const std::vector<std::int32_t>& argmax,
                          Shape in_shape, bool accumulate = false);
// Shorthand: in_shape = [N, C, 2 Ho, 2 Wo] (the input had even sizes).
void max_pool2x2_backward(Tensor& d_in, const Tensor& d_out, const std::vector<std::int32_t>& argmax);

void relu_forward(Tensor& out, const Tensor& in);
void relu_backward(Tensor& d_in, const Tensor& d_out, const Tensor& out);

// Channel concat: a [N, Ca, H, W], b [N, Cb, H, W] -> out [N, Ca + Cb, H, W].
void concat_forward(Tensor& out, const Tensor& a, const Tensor& b);
// Splits d_out into d_a and d_b; with accumulate d_a gets += (d_b is always written).
void concat_backward(Tensor& d_a, Tensor& d_b, const Tensor& d_out, int ca, bool accumulate_a = false);
void concat_backward(Tensor& d_a, Tensor& d_b, const Tensor& d_out);  // ca from d_a's shape

// Per-row affine: out[n, c, h, w] = gain[c, h] * in[n, c, h, w] + offset[c, h], one gain and
// offset per output channel and row (the UNet's per-laser effect: a PGM row is one laser).
//   in [N, C, H, W], gain and offset [C * H] (row-major: channel, then row).
void row_affine_forward(Tensor& out, const Tensor& in, const float* gain, const float* offset);
// Writes d_in (=), accumulates d_gain and d_offset (+=).
void row_affine_backward(Tensor& d_in, float* d_gain, float* d_offset, const Tensor& d_out, const Tensor& in,
                         const float* gain);

// Lookup base: a fitted table's prediction read off the input itself, so a model that adds it
// needs nothing at inference but its usual input. Per cell: group g = the first of `classes`
// one-hot channels (from class_channel) above 0.5, else `classes` (no group); range bin b =
// floor(range input / bin_width) clamped to [0, range_bins); out = table[g * range_bins + b] +
// beam[h] where the range input is > 0, 0 in empty cells (no return).
//   x [N, C, H, W] (H = rows), table [(classes + 1) * range_bins], beam [rows] -> out [N, 1, H, W].
struct LookupBaseConfig {
  int classes = 0;        // 0: no lookup base
  int class_channel = 0;  // first one-hot class channel of the input
  int range_channel = 0;  // the input channel holding range / range_max
  int range_bins = 0;
  float bin_width = 0.f;  // in range-input units (5 m / range_max)
  int rows = 0;           // one beam (laser) offset per row
  bool operator==(const LookupBaseConfig&) const = default;
};
// Table index of each cell of x, [N * H * W] (-1: empty cell): what forward looks up and what a
// fit of the table accumulates over.
void lookup_base_keys(std::vector<std::int32_t>& keys, const Tensor& x, const LookupBaseConfig& c);
void lookup_base_forward(Tensor& out, const Tensor& x, const LookupBaseConfig& c, const float* table,
                         const float* beam);
// Accumulates (+=) d_table and d_beam; the base is piecewise constant in x (no input gradient).
void lookup_base_backward(float* d_table, float* d_beam, const Tensor& d_out, const Tensor& x,
                          const LookupBaseConfig& c);

// Test-only fault injection: when set, the named backward pass puts one value at a wrong index,
// so the gradient-check tests can prove that they catch such a bug. Never set outside tests.
namespace testhook {
enum class Fault {
  none,
  conv2d_input,
  conv2d_weight,
  conv2d_bias,
  conv_transpose_input,
  conv_transpose_weight,
  max_pool,
  relu,
  concat,
  row_affine,
  lookup_base,
};
extern Fault fault;
}  // namespace testhook

}  // namespace lidarsim::nn
