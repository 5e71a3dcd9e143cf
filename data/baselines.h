#pragma once
// Lookup-table baselines for intensity, fitted on the training cells of a dataset and evaluated
// (MAE, RMSE) on its validation cells (data/split.h), the yardstick the UNet must beat:
//   global mean          one number
//   per-class mean       mean intensity per class id
//   class x range bin    5 m range bins [0,5), [5,10), ..., [75,80), [80,inf)
//   class x beam row     mean per class and PGM row
// A key never seen in training falls back to its class mean, then to the global mean. Only
// cells with a return (mask 1) count.
#include <cstdint>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "data/split.h"

namespace lidarsim::data {

struct Metrics {
  double mae = 0, rmse = 0;
  long cells = 0;
};

struct BaselineResult {
  std::string name;  // "global_mean", "class_mean", "class_x_range", "class_x_row"
  Metrics validation;
  Metrics training;
};

inline constexpr double kRangeBinM = 5.0;
inline constexpr int kRangeBins = 17;  // 16 bins of 5 m up to 80 m, then one for >= 80 m
int range_bin(double range_m);

// All four baselines; the dataset needs the "class" and "range" channels.
std::vector<BaselineResult> evaluate_baselines(const Dataset& dataset, const SectorSplit& split = reference_split());

// The same four fitted on every cell with a return of `training` (other places) and scored on every
// cell of `held_out` (a place held out whole: data/place_split.h). use_class false: every class
// reads as 0 (per-class mean = global mean, class x range = range bins, class x row = rows), the
// lookups of a model without the class channel.
std::vector<BaselineResult> evaluate_baselines_across(const std::vector<const Dataset*>& training,
                                                      const Dataset& held_out, bool use_class = true);

// MAE/RMSE of a prediction [N, 1, H, W] against the dataset's target on the split's validation
// (or training) cells; for comparing a network with the baselines on the same cells.
Metrics evaluate_prediction(const Dataset& dataset, const nn::Tensor& prediction, bool validation,
                            const SectorSplit& split = reference_split());

// Running MAE/RMSE, for scoring frame by frame (streaming validation): frames added in the
// order evaluate_prediction takes them give its numbers exactly.
struct ErrorSums {
  double abs = 0, sq = 0;
  long n = 0;
  void add(double error);
  Metrics get() const;
};
// Adds one frame's cells that have a return and whose column has the validation (or training)
// role; prediction, target and mask are [rows * cols], roles from SectorSplit::roles.
void add_frame_errors(ErrorSums& sums, const float* prediction, const float* target, const float* mask,
                      const std::vector<std::uint8_t>& roles, int rows, int cols, bool validation);

// A Markdown table of the results.
std::string baseline_table(const std::vector<BaselineResult>& results);

}  // namespace lidarsim::data
