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

#include "qualify/objects/object_candidates.h"
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

// The spread form to add once `picked` (a spread form whose score clears `threshold`, whose own 95 %
// interval lies above 0 and whose selection-aware bound does too) has been picked: of the spread
// forms of its feature and target, the one with the best held-out score whose score clears the
// threshold and whose own interval lies above 0 (picked itself when none scores higher). The bound
// (object_selection.h) answers "does any of some 240 spread forms explain a spread?", and it is the
// winner's curse over all of them that it corrects; once one form of a feature x target clears
// it, which of that feature's few forms (table, window, line) to add is a choice among forms
// judged on the same held-out tracks. A line's bootstrap interval is wider than the table's (it
// rests on the few objects at the feature's far end, where it differs from the table most), so
// a line that beats the table held out could fail the bound the table clears (a speed spread:
// line 0.237 [0.111, 0.488], table 0.206 [0.171, 0.246]; against the truth the line cuts the
// sigma error to 0.42 x, the table to 0.70 x).
int best_form_of_picked(const std::vector<Candidate>& cands, int picked, double threshold);

}  // namespace lidarsim::qualify::obj
