#pragma once
// Return model (raydrop) qualification: fit on some places' measured scans, score on a place the
// fit never saw. `lidar-qualify returns` (qualify/returns/returns_cli.cpp) runs it per held-out place;
// the scoring here is also what the tests call.
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "pgm/return_target.h"
#include "sensor/return_model.h"

namespace lidarsim::qualify {

// Scores of predicted return probabilities against the measured returns of the geometry cells
// (Return and Drop cells of the targets).
struct ReturnScore {
  long long cells = 0;          // geometry cells scored
  double measured_rate = 0;     // returns / geometry cells
  double predicted_rate = 0;    // mean predicted probability
  double auroc = 0.5;           // per cell; 0.5 for a constant prediction
  double brier = 0;             // mean (p - returned)^2
  // Total variation between the predicted and the measured joint distribution of (group, return)
  // for groups laser, 5 m range bin and class: sum over groups of share * |mean p - rate|.
  double tv_laser = 0, tv_range = 0, tv_class = 0;
  // The same between two halves of the measured cells (alternating 32-column sectors): how far
  // two samples of this place's own rates lie apart, the floor of a TV on this much data.
  double tv_laser_halves = 0, tv_range_halves = 0, tv_class_halves = 0;
};

// The model's probability per cell (use_laser: the laser chain, else the laser-free one); a null
// model is the baseline "every geometry cell returns" (p = 1).
ReturnScore score_returns(const std::vector<pgm::ReturnTarget>& targets, const sensor::ReturnModel* model,
                          bool use_laser, double range_bin_m = 5);

nlohmann::json to_json(const ReturnScore& s);

// `lidar-qualify returns ...` (argv[0] = "returns"); prints a table, writes report.json/.md.
int run_returns(int argc, char** argv);

}  // namespace lidarsim::qualify
