// The azimuth cross-fit of the intensity loop on scans of one scenery (intensity_internal.h,
// scenery_cross_fit).
//
// Why classes x row blocks, crossed. A gain of the sensor over a window of azimuth multiplies
// every return in those columns, whatever it hits and at whichever laser; the base's error on the
// scenery there (a wall darker than its class's mean, a wet patch of road) belongs to one object:
// one class, a band of rows. A form fitted on the other class group alone would still carry a
// dark object that spans classes in one band of rows (a wet road and its kerb); fitted on the
// other row block alone, it would carry one tall object of one class (a building over every row
// of its columns). Fitted on the cells that share neither the class group nor the row block, only
// what is common to the columns across both carries over, as a sensor's gain does.
#include <algorithm>
#include <cstdio>
#include <map>

#include "data/baselines.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/windows.h"

namespace lidarsim::qualify::intensity_detail {

namespace {

std::string pct(double share) {
  char b[32];
  std::snprintf(b, sizeof b, "%.0f %%", 100 * share);
  return b;
}

// Two groups of classes with about equal cell counts: the largest class first, each into the
// group with fewer cells so far (deterministic: ties by class id).
std::map<int, int> class_groups(const std::vector<int>& cls) {
  std::map<int, long> count;
  for (int c : cls) ++count[c];
  std::vector<std::pair<long, int>> order;
  for (const auto& [c, n] : count) order.push_back({-n, c});
  std::sort(order.begin(), order.end());
  std::map<int, int> group;
  long size[2] = {0, 0};
  for (const auto& [neg, c] : order) {
    const int g = size[1] < size[0] ? 1 : 0;
    group[c] = g, size[g] -= neg;
  }
  return group;
}

// The row splitting the cells into two halves (rows below it: block 0).
int median_row(std::vector<int> rows) {
  if (rows.empty()) return 0;
  std::nth_element(rows.begin(), rows.begin() + rows.size() / 2, rows.end());
  return rows[rows.size() / 2];
}

}  // namespace

void scenery_cross_fit(Pooled& p, const std::string& columns_reason) {
  p.azimuth_scenery = {};
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  const std::map<int, int> by_class = class_groups(p.cls);
  int split_row = median_row(p.row);
  // All cells on one side of the median (few rows with returns): the block boundary above it.
  if (std::none_of(p.row.begin(), p.row.end(), [&](int r) { return r < split_row; })) ++split_row;
  std::vector<int> group(p.size());
  long quadrant[4] = {0, 0, 0, 0};
  for (size_t i = 0; i < p.size(); ++i) {
    group[i] = 2 * by_class.at(p.cls[i]) + (p.row[i] >= split_row ? 1 : 0);
    ++quadrant[group[i]];
  }
  const bool two_classes = by_class.size() >= 2;
  const bool two_blocks = quadrant[0] + quadrant[2] > 0 && quadrant[1] + quadrant[3] > 0;
  auto undecided = [&](const std::string& why) {
    p.azimuth_undecided = columns_reason + "; across classes x row blocks in the same columns: " + why;
  };
  if (!two_classes || !two_blocks) {
    undecided(!two_classes ? "1 class" : "1 block of rows");
    return;
  }
  // Coverage: a cell's azimuth form is fitted on the opposite group's cells at its azimuth; where
  // the opposite group has (almost) none there, the form falls back to no effect, and where that
  // holds for most cells the score says nothing either way.
  BinnedTable fine;
  fine.edges = equal_count_edges(p.feature[iaz], kSceneryFineBins);
  std::vector<std::array<long, 4>> n(fine.edges.size() + 1, std::array<long, 4>{0, 0, 0, 0});
  for (size_t i = 0; i < p.size(); ++i) ++n[fine.bin(p.feature[iaz][i])][group[i]];
  long covered = 0;
  for (const auto& bin : n)
    for (int g = 0; g < 4; ++g)
      if (bin[3 - g] >= kSceneryMinCellsPerBin) covered += bin[g];
  const double coverage = p.size() ? static_cast<double>(covered) / p.size() : 0;
  if (coverage < kSceneryMinCoverage) {
    undecided("only " + pct(coverage) + " of the held-out cells have at least " +
              std::to_string(kSceneryMinCellsPerBin) + " cells of the other classes in the other rows at their " +
              "azimuth (" + pct(kSceneryMinCoverage) + " needed)");
    return;
  }
  p.azimuth_undecided.clear();
  CrossFit& c = p.azimuth_scenery;
  c.group = std::move(group), c.groups = 4, c.crossed = true;
  c.by = "classes x row blocks in the same columns (" + std::to_string(by_class.size()) +
         " classes in 2 groups of about equal size, rows split at row " + std::to_string(split_row) +
         "; each fitted on the cells sharing neither, " + pct(coverage) + " of the cells covered), because " +
         columns_reason;
}

namespace {

// Per fold, the lookup's levels refitted with the gain G divided out: sum m G / sum G^2 per key
// over the fold's fit cells; per pooled cell (any group) its level, the plain lookup where its
// key has no fit cells.
template <class Gain>
std::vector<double> levels_with_gain(const std::vector<Fold>& folds, const Pooled& p, Gain gain, size_t iaz) {
  std::vector<double> level = p.lookup;
  for (size_t k = 0; k < folds.size(); ++k) {
    const IntensityCells& c = folds[k].cells;
    auto key = [&](size_t i) { return long(c.cls[i]) * 1000 + data::range_bin(c.feature[0][i]); };
    std::map<long, std::array<double, 2>> t;  // key -> (sum m G, sum G^2)
    for (size_t i = 0; i < c.size(); ++i)
      if (!c.held_out[i]) {
        const double G = gain(c.feature[iaz][i]);
        auto& e = t[key(i)];
        e[0] += c.measured[i] * G, e[1] += G * G;
      }
    for (size_t j = 0; j < folds[k].held.size(); ++j) {
      const auto it = t.find(key(folds[k].held[j]));
      if (it != t.end() && it->second[1] > 0) level[p.offset[k] + j] = it->second[0] / it->second[1];
    }
  }
  return level;
}

}  // namespace

std::vector<double> lookup_with_azimuth_gain(const std::vector<Fold>& folds, const Pooled& p, Form form,
                                             const std::vector<double>& edges, const std::vector<double>& fine) {
  const CrossFit& cf = p.azimuth_scenery;
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  const std::vector<double>&x = p.feature[iaz], &range = p.feature[0];
  std::vector<double> out = p.lookup;
  BinnedTable fine_bins;
  fine_bins.edges = fine;
  for (int g = 0; g < cf.groups; ++g) {
    std::vector<size_t> fit;
    for (size_t i = 0; i < p.size(); ++i)
      if (cf.group[i] != g && cf.fits(g, cf.group[i])) fit.push_back(i);
    if (fit.empty()) continue;
    std::vector<long> fine_count(fine.size() + 1, 0);
    for (size_t i : fit) ++fine_count[fine_bins.bin(x[i])];
    FittedForm f, one;
    // As score_form: where the opposite group has no cells at an azimuth, the one-bin gain.
    auto gain = [&](double az) {
      if (!one.ok()) return 1.0;
      const bool known = f.ok() && (form == Form::WindowGain ? fine_count[fine_bins.bin(az)] > 0
                                                             : f.table.count[f.table.bin(az)] > 0);
      return 1 + (known ? f : one).delta(az, 1.0, 0.0);
    };
    // Alternating least squares: the gain fitted on the opposite group's cells over the levels
    // refitted with the previous gain (this group's own gain: no level of a fit cell comes from
    // a gain fitted on this group's cells), then the levels with the new gain.
    std::vector<double> level = p.lookup;
    for (int round = 0; round < kJointRounds; ++round) {
      std::vector<double> r(p.size(), 0.0), rf;
      for (size_t i : fit) rf.push_back(p.measured[i] - level[i]);
      const Winsor w = winsor_limits(rf);
      for (size_t i : fit) r[i] = w(p.measured[i] - level[i]);
      f = fit_form(form, edges, fine, x, r, level, range, fit);
      one = fit_form(Form::GainTable, {}, {}, x, r, level, range, fit);
      level = levels_with_gain(folds, p, gain, iaz);
    }
    for (size_t i = 0; i < p.size(); ++i)
      if (cf.group[i] == g) out[i] = gain(x[i]) * level[i];
  }
  return out;
}

bool joint_azimuth_gain(const Pooled& p, const std::string& feature, Form form) {
  return (form == Form::GainTable || form == Form::WindowGain) && cross_fit_for(p, feature).crossed;
}

CrossFit cross_fit_for(const Pooled& p, const std::string& feature) {
  if (feature == "azimuth" && p.azimuth_scenery.groups > 0) return p.azimuth_scenery;
  return {p.group, p.groups, false, p.group_by};
}

}  // namespace lidarsim::qualify::intensity_detail
