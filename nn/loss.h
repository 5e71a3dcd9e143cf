#pragma once
// Masked MSE plus L2 weight regularisation, as in the paper (and the extra heads' losses below):
//   loss = sum(mask * (pred - target)^2) / max(1, sum(mask))  +  lambda * sum(w^2 over weights)
// Biases are not regularised. Gradients are written (=) to d_pred and added (+=) to the arena.
#include "nn/params.h"
#include "nn/tensor.h"

namespace lidarsim::nn {

struct LossParts {
  double data = 0;   // the masked mean squared error
  double l2 = 0;     // lambda * sum of squared weights
  double total() const { return data + l2; }
  long valid = 0;    // cells with mask != 0
};

// pred, target, mask: [N, 1, H, W]; mask holds 0 or 1 as float. `denominator` > 0 divides by
// that count of cells instead of this batch's own: data-parallel training passes the count over
// every process's part of the batch, so the parts' losses and gradients add up to the whole's.
LossParts masked_mse(const Tensor& pred, const Tensor& target, const Tensor& mask, Tensor* d_pred,
                     long denominator = 0);
// The extra heads' losses (nn/heads.h), each a masked mean with the same `denominator` convention
// and the same contract: every tensor [N, 1, H, W], gradients written (=), 0 outside the mask,
// a non-finite value in a masked-in cell is an Error naming the tensor and flat index.

// Binary cross-entropy on logits z against a target y in [0, 1] (a return probability head), in
// the log-sum-exp form that stays finite for any finite z:
//   l = max(z, 0) - z y + log(1 + exp(-|z|)),   dl/dz = sigmoid(z) - y.
LossParts masked_bce_logits(const Tensor& logit, const Tensor& target, const Tensor& mask, Tensor* d_logit,
                            long denominator = 0);

// Negative log-likelihood of y under a distribution with predicted mean mu and log-scale s (an
// intensity-spread head). s is clamped to [min, max] before use, as torch.clamp does (no gradient
// to s where it is clamped): exp(-7) = 9e-4 is below any sensor's intensity resolution (8 bits:
// 1 / 255 = 4e-3) on a 0..1 scale, and exp(3) = 20 above any spread on it; outside those bounds
// the density would overflow or underflow in float. The constants are kept, so the losses are
// true NLLs (nats per cell) and the two families compare.
//   gaussian (s = log sigma): l = s + (y - mu)^2 / (2 sigma^2) + log(2 pi) / 2
//   laplace  (s = log b):     l = s + |y - mu| / b + log 2        (d|x|/dx at 0 taken as 0)
enum class Spread { gaussian, laplace };
struct LogScaleClamp {
  float min = -7.f;
  float max = 3.f;
  bool operator==(const LogScaleClamp&) const = default;
};
// d_mean may be null: no gradient to the mean (the spread is then fitted around a mean trained by
// its own loss, as the mean head keeps the paper's masked MSE).
LossParts masked_nll(Spread family, const Tensor& mean, const Tensor& log_scale, const Tensor& target,
                     const Tensor& mask, Tensor* d_mean, Tensor* d_log_scale, long denominator = 0,
                     LogScaleClamp clamp = {});

// Adds lambda * sum((w - c)^2) over decaying parameters (c = their decay_center: 0 for weights,
// 1 for the row-affine gain) and, when grads is true, 2 lambda (w - c) to the arena's gradients.
double l2_penalty(ParamArena& params, float lambda, bool grads);

}  // namespace lidarsim::nn
