#pragma once
// The spread_line form of the object loop's candidates (object_candidates.h; internal to
// qualify/): an error's sigma that grows (or falls) linearly with a feature,
//   sigma_i = sd_i x level[group_i] x g(x_i),  g(x) = 1 + (rho - 1) (clamp(x, q1, q99) - q1) / (q99 - q1),
// with q1, q99 the 1 and 99 % quantiles of x on the fit split, sd_i the model's sigma of the
// record's cell and one level per group of cells (class x range bin). The levels are refitted with
// rho because the model's sigma per cell already averages the growth over the cell's objects: a
// cell of parked cars and one of fast ones on speed, the near and far halves of a 10 m range bin.
// Fitted by maximum likelihood of the squared standardised residuals u2 = (residual / sd)^2: for
// a given rho each level has its closed-form maximum (level^2 = the group's mean of u2 / g^2), and
// rho minimises the profile negative log-likelihood over log rho in [-kMaxLogRatio, kMaxLogRatio].
// rho = 1 with every level 1 is the model without the form (sd is the cell's RMS residual), so the
// held-out score of the form is its gain over the model.
#include <vector>

#include "qualify/residual.h"

namespace lidarsim::qualify::obj {

inline constexpr double kMaxLogRatio = 2.5;  // g(q99) / g(q1) within [e^-2.5, e^2.5] = [0.08, 12]

struct ScaleLine {
  BinnedTable scale;           // g as kLineBins equal-width bins over [q1, q99], flat beyond
  std::vector<double> level;   // per group
  double ratio = 1;            // rho = g(q99) / g(q1)
};

// x: the feature; u2: squared residual in units of its cell's sd; group[i] in [0, groups).
ScaleLine fit_scale_line(const std::vector<double>& x, const std::vector<double>& u2, const std::vector<int>& group,
                         int groups);

}  // namespace lidarsim::qualify::obj
