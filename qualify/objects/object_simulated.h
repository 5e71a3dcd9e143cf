#pragma once
// What the KPI manager really uses per truth object with a given model (internal to qualify/):
// the loop's "before_simulated" / "after_simulated" re-simulate held-out sequences with these.
#include <array>
#include <cstdint>
#include <map>
#include <vector>

#include "sensor/kpi_fit.h"
#include "sensor/kpi_model.h"

namespace lidarsim::qualify::obj {

// The conditional mean error of parameter p the KPI manager injects per truth object (model
// with its noise switched off), keyed by (sequence, frame, id).
std::map<std::array<int, 3>, double> simulated_mean_error(const std::vector<sensor::CalibrationSequence>& seqs,
                                                          const std::vector<int>& which, sensor::KpiModel model,
                                                          sensor::KpiParam p, std::uint64_t seed);

// The error of parameter p the KPI manager injects per truth object with its noise on (one draw).
std::map<std::array<int, 3>, double> simulated_error_draw(const std::vector<sensor::CalibrationSequence>& seqs,
                                                          const std::vector<int>& which, const sensor::KpiModel& model,
                                                          sensor::KpiParam p, std::uint64_t seed);

// The detection probability the KPI manager uses per truth object (its misses are draws from it).
std::map<std::array<int, 3>, double> simulated_detection_probability(
    const std::vector<sensor::CalibrationSequence>& seqs, const std::vector<int>& which, const sensor::KpiModel& model,
    std::uint64_t seed);

}  // namespace lidarsim::qualify::obj
