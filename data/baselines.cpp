#include "data/baselines.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include "common/error.h"
#include "pgm/materials.h"

namespace lidarsim::data {

int range_bin(double range_m) {
  const int b = static_cast<int>(std::floor(range_m / kRangeBinM));
  return std::clamp(b, 0, kRangeBins - 1);
}

namespace {

struct Cell {
  int cls, row, bin;
  float y;
  bool validation;
};

struct Mean {
  double sum = 0;
  long n = 0;
  void add(double v) { sum += v, ++n; }
  double get(double fallback) const { return n ? sum / n : fallback; }
};

using Accum = ErrorSums;

}  // namespace

// The four lookups fitted on the cells not marked validation, scored on both sides.
static std::vector<BaselineResult> score_cells(const std::vector<Cell>& cells);

void ErrorSums::add(double e) { abs += std::abs(e), sq += e * e, ++n; }
Metrics ErrorSums::get() const { return {n ? abs / n : 0, n ? std::sqrt(sq / n) : 0, n}; }

void add_frame_errors(ErrorSums& sums, const float* prediction, const float* target, const float* mask,
                      const std::vector<std::uint8_t>& roles, int rows, int cols, bool validation) {
  const std::size_t plane = static_cast<std::size_t>(rows) * cols;
  const std::uint8_t want_role = validation ? kValidation : kTrain;
  for (std::size_t i = 0; i < plane; ++i) {
    if (mask[i] <= 0 || roles[i % cols] != want_role) continue;
    sums.add(static_cast<double>(prediction[i]) - target[i]);
  }
}

std::vector<BaselineResult> evaluate_baselines(const Dataset& d, const SectorSplit& split) {
  const int ci = d.channel_index("class"), ri = d.channel_index("range");
  const int H = d.rows(), W = d.cols();
  std::vector<Cell> cells;
  for (int n = 0; n < d.size(); ++n) {
    const auto roles = split.roles(W, n < static_cast<int>(d.frames.size()) ? d.frames[n] : "");
    const float* cls = d.pgm.channel(n, ci);
    const float* rng = d.pgm.channel(n, ri);
    const float* mask = d.mask.image(n);
    const float* y = d.target.image(n);
    for (int r = 0; r < H; ++r)
      for (int c = 0; c < W; ++c) {
        const std::size_t i = static_cast<std::size_t>(r) * W + c;
        if (mask[i] <= 0 || roles[c] == kGuard) continue;  // guard cells: neither fitted nor scored
        cells.push_back({static_cast<int>(cls[i]), r, range_bin(rng[i]), y[i], roles[c] == kValidation});
      }
  }
  return score_cells(cells);
}

// Every cell with a return of `d`, on the given side, its class read or (without) set to 0.
static void add_all_cells(std::vector<Cell>& cells, const Dataset& d, bool validation, bool use_class) {
  const int ci = d.channel_index("class"), ri = d.channel_index("range");
  const int H = d.rows(), W = d.cols();
  for (int n = 0; n < d.size(); ++n) {
    const float* cls = d.pgm.channel(n, ci);
    const float* rng = d.pgm.channel(n, ri);
    const float* mask = d.mask.image(n);
    const float* y = d.target.image(n);
    for (int r = 0; r < H; ++r)
      for (int c = 0; c < W; ++c) {
        const std::size_t i = static_cast<std::size_t>(r) * W + c;
        if (mask[i] <= 0) continue;
        cells.push_back({use_class ? static_cast<int>(cls[i]) : 0, r, range_bin(rng[i]), y[i], validation});
      }
  }
}

std::vector<BaselineResult> evaluate_baselines_across(const std::vector<const Dataset*>& training,
                                                      const Dataset& held_out, bool use_class) {
  std::vector<Cell> cells;
  for (const Dataset* d : training) add_all_cells(cells, *d, false, use_class);
  add_all_cells(cells, held_out, true, use_class);
  return score_cells(cells);
}

static std::vector<BaselineResult> score_cells(const std::vector<Cell>& cells) {
  Mean global;
  std::map<int, Mean> by_class;
  std::map<std::pair<int, int>, Mean> by_class_bin, by_class_row;
  for (const Cell& c : cells) {
    if (c.validation) continue;
    global.add(c.y);
    by_class[c.cls].add(c.y);
    by_class_bin[{c.cls, c.bin}].add(c.y);
    by_class_row[{c.cls, c.row}].add(c.y);
  }
  if (global.n == 0) throw Error("baselines: no training cells with a return");
  const double g = global.get(0);
  auto class_mean = [&](int cls) {
    auto it = by_class.find(cls);
    return it == by_class.end() ? g : it->second.get(g);
  };
  auto lookup = [&](const std::map<std::pair<int, int>, Mean>& table, int cls, int key) {
    auto it = table.find({cls, key});
    return it == table.end() ? class_mean(cls) : it->second.get(class_mean(cls));
  };
  std::vector<BaselineResult> results = {{"global_mean", {}, {}}, {"class_mean", {}, {}},
                                         {"class_x_range", {}, {}}, {"class_x_row", {}, {}}};
  Accum acc[4][2];
  for (const Cell& c : cells) {
    const double pred[4] = {g, class_mean(c.cls), lookup(by_class_bin, c.cls, c.bin), lookup(by_class_row, c.cls, c.row)};
    for (int k = 0; k < 4; ++k) acc[k][c.validation ? 1 : 0].add(pred[k] - c.y);
  }
  for (int k = 0; k < 4; ++k) {
    results[k].training = acc[k][0].get();
    results[k].validation = acc[k][1].get();
  }
  return results;
}

Metrics evaluate_prediction(const Dataset& d, const nn::Tensor& prediction, bool validation, const SectorSplit& split) {
  const nn::Shape want{d.size(), 1, d.rows(), d.cols()};
  if (!(prediction.shape() == want))
    throw Error("evaluate_prediction: prediction shape " + prediction.shape().str() + ", expected " + want.str());
  ErrorSums acc;
  for (int n = 0; n < d.size(); ++n) {
    const auto roles = split.roles(d.cols(), n < static_cast<int>(d.frames.size()) ? d.frames[n] : "");
    add_frame_errors(acc, prediction.image(n), d.target.image(n), d.mask.image(n), roles, d.rows(), d.cols(), validation);
  }
  return acc.get();
}

std::string baseline_table(const std::vector<BaselineResult>& results) {
  std::string s = "| baseline | val MAE | val RMSE | val cells | train MAE | train cells |\n|---|---|---|---|---|---|\n";
  char line[256];
  for (const auto& r : results) {
    std::snprintf(line, sizeof line, "| %s | %.4f | %.4f | %ld | %.4f | %ld |\n", r.name.c_str(), r.validation.mae,
                  r.validation.rmse, r.validation.cells, r.training.mae, r.training.cells);
    s += line;
  }
  return s;
}

}  // namespace lidarsim::data
