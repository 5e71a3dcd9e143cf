#pragma once
// Masked MSE plus L2 weight regularisation, as in the paper:
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
// Adds lambda * sum((w - c)^2) over decaying parameters (c = their decay_center: 0 for weights,
// 1 for the row-affine gain) and, when grads is true, 2 lambda (w - c) to the arena's gradients.
double l2_penalty(ParamArena& params, float lambda, bool grads);

}  // namespace lidarsim::nn
