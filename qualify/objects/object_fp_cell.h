#pragma once
// The fp_rate_cell form of the object loop's false positives (internal to qualify/): a hot spot of
// false detections in a rectangle of range x azimuth (a reflective sign, a pole the detector keeps
// seeing) on top of a background whose range and azimuth are independent, as the base model has it:
//   intensity(r, a) = lambda_b f(r) h(a) + lambda_c U[r0, r1)(r) U[a0, a1)(a).
// A window in range alone (fp_rate_window) gives the rows of its bin the bin's own azimuth quantiles,
// a mixture the 21 quantiles blur and the 20 pseudo false positives of the prior shrink back toward
// the class's marginal; and where the cell holds most of a class's false positives the base's two
// marginals already put most of it in the right row and column, so what is left is joint: the
// background's mass the product puts beside the cell in both directions. The cell form fits that.
// Fit (on a fold's fit split, per class or with one rectangle for every class, each class with its
// own rates): the rectangle's edges are runs of equal-count fine bins of the fitted false positives'
// range and azimuth (2 x bins each), chosen by the Poisson log-likelihood of the counts on that fine
// grid; for a rectangle, the background's range shares come from the false positives outside its
// azimuths and its azimuth shares from those outside its ranges (independence), its rate from the
// count outside the rectangle over the background's mass there, the cell's rate from what the
// rectangle holds beyond the background (>= 0), spread uniformly over it. The rectangle must hold
// kFpWindowSide fit false positives and leave some range and some azimuth outside it.
// Written as the KPI model's fp_table over range (bins below, inside and above the cell's ranges; a
// step when it reaches an end): each bin's rate is the background's share of it (+ the cell's inside),
// its range and azimuth quantiles those of the mixture it holds, its score quantiles the class's.
#include "qualify/objects/object_false_positives.h"

namespace lidarsim::qualify::obj {

// The cell candidate for class `cls` (the other classes keep the base), or one rectangle for every
// class (-1). No rectangle qualifies: the base (feature 0, no cuts).
FpModel fit_fp_cell(const FpData& fit, const sensor::KpiModel& base, int bins, const FpGrid& g,
                    const PerClass<double>& floor, int cls);

// Quantiles (as lidar-calibrate stores them, 21) of weighted values: the KPI manager samples
// uniformly between neighbouring quantiles. Empty when the weights sum to 0.
std::vector<double> weighted_quantiles(std::vector<std::pair<double, double>> value_weight);

}  // namespace lidarsim::qualify::obj
