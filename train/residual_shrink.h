#pragma once
// Shrinking a residual UNet toward its lookup base (lidar-train --shrink-residual).
//
// With --lookup-base the model predicts table + r, where r is the network's residual. Trained on a
// few hundred columns of one street, r fits the training scenery and does not carry to held-out
// columns (README, "The best lookup as the base"). A factor s in [0, 1] on r (table + s r) is the
// standard hedge between the two: s = 0 is the table, s = 1 the network as trained. s is chosen on
// the early-stopping inner region, never on the scored regions, from a fixed grid, so it is one
// more setting fitted on held-in data. Scaling r means scaling the last layer that makes it: the
// per-row affine layer's gain and offset when present, else the 1x1 head's weight and bias.
#include <functional>
#include <utility>
#include <vector>

#include "nn/unet.h"

namespace lidarsim::train {

struct ResidualShrink {
  double scale = 1;                                  // the factor kept (the model holds it)
  std::vector<std::pair<double, double>> inner_mae;  // (factor, inner MAE) for every factor tried
};

// Multiplies the model's residual by `factor` (in place; factor 0 leaves the lookup base alone).
// Throws when the model has no lookup base.
void scale_residual(nn::UNet& model, double factor);

// Tries the factors 0, 0.05, ..., 1 on the model's current weights, scoring each with
// inner_mae() (the MAE on the inner region), and leaves the model scaled by the best one (ties go
// to the larger factor: the network as trained unless the inner region says otherwise).
ResidualShrink choose_residual_scale(nn::UNet& model, const std::function<double()>& inner_mae);

}  // namespace lidarsim::train
