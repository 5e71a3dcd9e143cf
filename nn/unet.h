#pragma once
// A configurable UNet as a fixed graph of layer calls (no general autograd).
//
// Architecture (matches tests/fixtures/torch_unet.py, parameter names included):
//   level l = 0..depth, channels c_l = base * 2^l
//   enc{l}.conv1, enc{l}.conv2: conv 3x3, padding 1, ReLU after each
//     (enc0.conv1 takes in_channels; enc{l}.conv1 takes c_{l-1} after a 2x2 max-pool; level
//      `depth` is the bottleneck)
//   for l = depth-1 .. 0:
//     dec{l}.up: transposed conv 2x2 stride 2, c_{l+1} -> c_l; its output is zero-padded at the
//       bottom/right to the skip's height/width (inputs need not be divisible by 2^depth)
//     concat([skip_l, up], channels) -> 2 c_l
//     dec{l}.conv1 (2 c_l -> c_l), dec{l}.conv2 (c_l -> c_l): conv 3x3, padding 1, ReLU
//   head: conv 1x1, c_0 -> out_channels, no activation
//   row_affine (only when row_affine_rows > 0): y[n, o, h, w] = gain[o, h] * head[n, o, h, w] +
//     offset[o, h], one gain and offset per output channel and row ("row_affine/gain" and
//     "row_affine/offset", shape [1, out_channels, rows, 1], initialised to 1 and 0 and pulled
//     toward them by the L2 term; stepped at 10x the learning rate). A PGM row is one laser, so this is a learned per-laser
//     gain/offset; inputs must then have exactly row_affine_rows rows.
//   lookup (only when lookup.classes > 0; nn/layers.h lookup_base): a fitted table's prediction
//     (class group x range bin + one offset per row) from the input itself. It is fed to enc0.conv1
//     as one more input channel (after the in_channels) and added to the output, so the network
//     learns the residual over the table. Its parameters "lookup/table" [1, 1, classes + 1,
//     range_bins] and "lookup/beam" [1, 1, rows, 1] are fitted on training cells
//     (train/lookup_fit.h), not trained: no gradient, no L2, optimizer step 0. The head starts at
//     zero, so the untrained model predicts exactly the table; with several outputs the base is
//     added to channel 0 only (the mean head).
//   heads (optional, nn/heads.h): what each output channel predicts and is trained with; empty =
//     out_channels plain outputs. The graph is the same for every head: only the 1x1 head's
//     output count changes.
// Default: depth 4, base 16 ("unet-ref" with 3 input channels: 6.07 GFLOP forward at 64 x 1024).
#include <cstdint>
#include <memory>
#include <string>

#include <vector>

#include "nn/heads.h"
#include "nn/kernel_plan.h"
#include "nn/layers.h"
#include "nn/params.h"
#include "nn/precision.h"
#include "nn/tensor.h"

namespace lidarsim::nn {

struct UNetConfig {
  int in_channels = 3;
  int out_channels = 1;
  int base = 16;
  int depth = 4;
  int row_affine_rows = 0;  // 0: no per-row affine layer
  LookupBaseConfig lookup{};  // classes 0: no lookup base
  std::vector<HeadKind> heads{};  // empty, or one per output channel (nn/heads.h check_heads)
  // Calibration factor of the spread head's scale (nn/heads.h): the scale at inference is
  // spread_scale * exp(clamp(s)). Fitted after training on cells the mean never trained on
  // (train/spread_calibration.h); 1 = uncalibrated (every model without a spread head).
  float spread_scale = 1.f;
  // The spread's residual shape and the targets' grid, fitted with the scale (nn/heads.h); empty:
  // the head's own Laplace/Gaussian.
  SpreadResidual spread_residual{};
  bool operator==(const UNetConfig&) const = default;
};

class UNet {
 public:
  explicit UNet(const UNetConfig& config);
  ~UNet();
  UNet(UNet&&) noexcept;
  UNet& operator=(UNet&&) noexcept;

  const UNetConfig& config() const { return config_; }
  // Sets config().spread_scale (finite, > 0); the weights are not touched.
  void set_spread_scale(float factor);
  // Sets config().spread_residual (checked; needs a spread head unless empty).
  void set_spread_residual(SpreadResidual residual);
  ParamArena& params() { return params_; }
  const ParamArena& params() const { return params_; }

  // He-normal weights (std = sqrt(2 / fan_in)), zero biases; deterministic for a seed.
  void init(std::uint64_t seed);

  // x: [N, in_channels, H, W] -> y: [N, out_channels, H, W]. Keeps activations for backward().
  void forward(const Tensor& x, Tensor& y);
  // Inference only: same result as forward(), without keeping what backward() needs; with bf16
  // inference on (nn/precision.h) the 3x3 convolutions run in bf16 with fp32 sums instead.
  // Keeps the packed weights of its convolutions across calls (nn/weight_cache.h).
  void predict(const Tensor& x, Tensor& y);

  // This model's inference precision and 3x3 algorithm; until set, the process defaults
  // (nn/precision.h, nn/conv_settings.h) at each call. A model owns everything its calls use
  // (activations, packed weights, these settings) and the ops keep their scratch per thread, so
  // different models may run in different threads at once; one model runs one call at a time.
  void set_inference_precision(InferencePrecision p) { precision_ = p; has_precision_ = true; }
  void set_conv3x3_path(detail::Conv3x3Path p) { conv3x3_ = p; has_conv3x3_ = true; }
  // This model's kernel choices (nn/kernel_plan.h): rule mode until set. Every conv shape the
  // model runs is recorded in it; a run saves it and a resumed run sets it back, so both take
  // the same kernels.
  KernelPlan& kernel_plan() { return *plan_; }
  const KernelPlan& kernel_plan() const { return *plan_; }
  void set_kernel_plan(KernelPlan plan) { *plan_ = std::move(plan); }
  // dy: [N, out_channels, H, W] of the last forward(); accumulates (+=) into params().grads().
  void backward(const Tensor& dy);

  double forward_flops(int n, int h, int w) const;  // multiply-adds x 2 of one forward pass

 private:
  UNetConfig config_;
  ParamArena params_;
  struct Workspace;  // activations, caches, argmax indices, packed weights; reused across calls
  std::unique_ptr<Workspace> ws_;
  InferencePrecision precision_ = InferencePrecision::fp32;
  bool has_precision_ = false;
  std::unique_ptr<KernelPlan> plan_ = std::make_unique<KernelPlan>();  // a pointer: ConvSettings holds it
  detail::Conv3x3Path conv3x3_ = detail::Conv3x3Path::automatic;
  bool has_conv3x3_ = false;
  // What the conv ops of one call run with (inference: precision and the packed-weight cache).
  detail::ConvSettings conv_settings(bool inference) const;
  // The steps of forward().
  void run_forward(const Tensor& x, Tensor& y, const detail::ConvSettings& cs);
  void check_input(const Shape& s) const;
  void take_input(const Tensor& x);
  const Tensor& forward_encoder();
  const Tensor& forward_decoder(const Tensor& deepest);
  void forward_head(const Tensor& below, Tensor& y);
};

}  // namespace lidarsim::nn
