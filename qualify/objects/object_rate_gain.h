#pragma once
// The rate_gain form of a detection candidate (internal to qualify/): a dropout that removes a
// share of the detections wherever the cell's probability stands (a soiled part of the window, a
// range beyond which the detector gives up) is a gain on the probability, not a shift of it:
//   p = q[class][range bin, visibility bin] x g(x),  g = g_in inside a window of x (a step when the
//   window reaches an end), 1 outside,
// with the cells q refitted jointly with the gain by the base model's own rule (sensor/kpi_fit.cpp:
// per range row, each visibility cell shrunk toward the row's prior with kDetectionPriorObjects
// pseudo-objects; a row of fewer objects than that takes the class's rate), every trial counted at
// its gain. With g = 1 everywhere this is the base model exactly; with a step in range it is what the
// base would fit if it knew the step: a row beyond the step that the fit split barely holds takes the
// class's rate x g_in, where the base gives it the class's rate, mostly made of detections before the
// step. An additive shift (rate_window) fitted on the base's residual sees only the part of a dropout
// that the base's cells miss in the fit split (the row straddling the edge), not the cells it gets
// wrong elsewhere.
// The window is chosen on the fit records: every run of up to `fine_bins` equal-count bins of x with
// at least `min_side` records inside and outside, by the Bernoulli log-likelihood of the joint fit,
// each edge costing the log of the fit records (a change point's BIC); each edge then refined on
// equal-count bins 4 times finer, within one bin of where it was found.
#include <vector>

#include "qualify/objects/object_terms.h"
#include "sensor/kpi_model.h"

namespace lidarsim::qualify::obj {

// y: detected 0/1 per fit record; cls (kObjectClasses), cell = range bin x nvis + visibility bin.
// Returned as a Refit: d = q - the base's probability for every cell of every class the base models
// (cells without fit records included), gain = g over the window's edges (pooled over classes), table = 0.
Refit fit_rate_gain(const std::vector<double>& x, const std::vector<double>& y, const std::vector<int>& cls,
                    const std::vector<int>& cells, const sensor::KpiModel& base, int nvis, int fine_bins = 40,
                    long min_side = 30);

// The cells q of the joint model for a given gain per record (g_i): the base model's detection rule
// (sensor/kpi_fit.cpp shrunk_detection_rates) with each record's trial counted as g_i. Per class, per
// cell; classes the base does not model are left empty.
PerClass<std::vector<double>> rate_gain_cells(const std::vector<double>& y, const std::vector<double>& g,
                                              const std::vector<int>& cls, const std::vector<int>& cells, int nrange,
                                              int nvis);

}  // namespace lidarsim::qualify::obj
