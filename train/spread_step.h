#pragma once
// lidar-train with a spread head (--heads mean,log_scale_...[,zero_logit]): the spread's NLL (and the
// zero head's BCE) trains only that channel's own output parameters, the mean's masked MSE everything else, so the mean is
// trained exactly as without the head (on a shared trunk the NLL's gradients moved the mean's
// features: its MAE 0.061 -> 0.114 on a synthetic set).
#include <vector>

#include "nn/heads.h"
#include "nn/tensor.h"
#include "nn/unet.h"

namespace lidarsim::train {

// Scratch kept between steps (no allocation per step once grown).
struct SpreadStepBuffers {
  nn::Tensor pred, d_pred, d_spread, zero_target;
  std::vector<float> spread_grads, l2_grads;
};

// Forward on x, the heads' losses against y where m > 0, and the gradients written to the model's
// arena as above (two backward passes over one forward), with the L2 term's (nn::l2_penalty,
// `lambda`) added before the mean's backward pass, as the step without heads adds it: kernels that
// accumulate into the arena chunk by chunk (the AVX-512 direct weight gradient) round otherwise.
// Returns the loss (data terms) and sets *l2 to the penalty.
double spread_step_gradients(nn::UNet& model, const std::vector<nn::HeadKind>& heads, const nn::Tensor& x,
                             const nn::Tensor& y, const nn::Tensor& m, float spread_weight, float lambda, double* l2,
                             SpreadStepBuffers& buffers);

// Sets the spread head's bias to the log of the first batch's mean absolute deviation: from a
// log-scale near 0 (scale 1, twenty times intensity's typical spread) a short run would spend its
// steps walking the bias down. A zero head's bias: the logit of the batch's share of zeros.
void start_spread_at(nn::UNet& model, const nn::Tensor& y, const nn::Tensor& m);

}  // namespace lidarsim::train
