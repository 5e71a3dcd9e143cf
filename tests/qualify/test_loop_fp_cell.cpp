// The fp_rate_cell form of the object loop's false positives (qualify/objects/object_fp_cell.h), and
// the rate_gain form's preference for a step where a window's far edge buys nothing
// (qualify/objects/object_rate_gain.h). File-local names carry the prefix FpCell / fpcell_.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_fp_cell.h"
#include "qualify/objects/object_rate_gain.h"
#include "qualify/windows.h"

using namespace lidarsim;
using namespace lidarsim::qualify;
using namespace lidarsim::qualify::obj;

namespace {

constexpr double fpcell_kDeg = 3.14159265358979323846 / 180;

// `frames` frames of false positives: per frame a Poisson number of Car (0.3) and Pedestrian (0.15)
// ones, uniform over 5-50 m and +-40 deg, and a Car hot spot of 0.7 per frame in 17.5-25.5 m x
// 1-14 deg (as the campaign's fp_cell family plants it).
ObjectSet fpcell_set(int frames, unsigned seed, double cell_rate = 0.7) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  ObjectSet s;
  for (int f = 0; f < frames; ++f) {
    s.frame_seq.push_back(0), s.frame_index.push_back(f), s.frame_truths.push_back(5);
    s.false_positives.push_back({0, 0, 0});
    auto add = [&](int cls, double r, double a) {
      s.fp_records.push_back({f, cls, r, a, 1 + 3 * u(rng)});
      ++s.false_positives.back()[cls];
    };
    for (const auto& [cls, rate] : {std::pair{0, 0.3}, std::pair{1, 0.15}}) {
      const int n = std::poisson_distribution<int>(rate)(rng);
      for (int k = 0; k < n; ++k) add(cls, 5 + 45 * u(rng), (-40 + 80 * u(rng)) * fpcell_kDeg);
    }
    const int n = cell_rate > 0 ? std::poisson_distribution<int>(cell_rate)(rng) : 0;
    for (int k = 0; k < n; ++k) add(0, 17.5 + 8 * u(rng), (1 + 13 * u(rng)) * fpcell_kDeg);
  }
  return s;
}

// The Car's false-positive rate error of `m` on `held` (object_false_positives.h fp_rate_error):
// RMS over the grid's cells of measured minus expected per frame, beyond the Poisson noise.
double fpcell_car_error(const FpModel& m, const FpData& held, const FpGrid& g) {
  std::vector<double> y(g.cells(), 0.0);
  for (const auto& fr : held.frames)
    for (const auto& [c, cell, n] : fr.counts)
      if (c == 0) y[cell] += n;
  const double n = static_cast<double>(held.frames.size());
  double s = 0;
  for (int k = 0; k < g.cells(); ++k) {
    const double rate = y[k] / n, d = rate - m.mu[0][0][k];
    s += d * d - rate / n;
  }
  return std::sqrt(std::max(0.0, s / g.cells()));
}

struct FpCellCase {
  FpGrid g;
  FpData fit, held;
  PerClass<double> floor{};
  sensor::KpiModel base;  // no classes: each class's base is its own false positives' marginals
};

FpCellCase fpcell_case() {
  FpCellCase c;
  const ObjectSet fit = fpcell_set(200, 11), held = fpcell_set(2000, 12);
  c.g = fp_grid(fit);
  c.fit = fp_data(fit, c.g), c.held = fp_data(held, c.g);
  c.floor = fp_floor(c.fit, c.g.cells());
  return c;
}

}  // namespace

// The cell's rectangle is found, and its model cuts the Car's held-out rate error to <= 0.7 x the
// base's (the product of the class's range and azimuth marginals), where the best window in range
// or in azimuth alone does not get there.
TEST(FpCellForm, FindsTheRectangleAndCutsTheRateErrorWhereAWindowInOneAttributeDoesNot) {
  const FpCellCase c = fpcell_case();
  FpModel base = fp_base(c.base, c.fit);
  base.compile(c.g, c.floor);
  const FpModel cell = fit_fp_cell(c.fit, c.base, 10, c.g, c.floor, 0);
  ASSERT_GE(cell.cell_rate, 0) << "a cell was fitted";
  EXPECT_NEAR(cell.cell[0], 17.5, 1.5);
  EXPECT_NEAR(cell.cell[1], 25.5, 1.5);
  EXPECT_NEAR(cell.cell[2] / fpcell_kDeg, 1, 3);
  EXPECT_NEAR(cell.cell[3] / fpcell_kDeg, 14, 3);
  EXPECT_NEAR(cell.cell_rate, 0.7, 0.15);
  const double e0 = fpcell_car_error(base, c.held, c.g), e_cell = fpcell_car_error(cell, c.held, c.g);
  const FpModel wr = fit_fp_model(c.fit, c.base, 0, true, 10, c.g, c.floor, 0);
  const FpModel wa = fit_fp_model(c.fit, c.base, 1, true, 10, c.g, c.floor, 0);
  const double e_wr = fpcell_car_error(wr, c.held, c.g), e_wa = fpcell_car_error(wa, c.held, c.g);
  EXPECT_LE(e_cell, 0.7 * e0) << "base " << e0 << ", cell " << e_cell;
  EXPECT_LT(e_cell, std::min(e_wr, e_wa)) << "base " << e0 << ", range window " << e_wr << ", azimuth window " << e_wa;
}

// The cell written as the KPI model's fp_table over range: bins below, inside and above the cell's
// ranges, whose rates add up to the class's fitted rate, the cell's bin holding the cell's rate.
TEST(FpCellForm, WritesARangeTableWhoseInsideBinHoldsTheCell) {
  const FpCellCase c = fpcell_case();
  sensor::KpiModel m;
  m.classes["Car"].false_positive_rate = 1.0;
  m.classes["Car"].fp_range_quantiles = {5, 50};
  m.classes["Car"].fp_azimuth_quantiles = {-0.7, 0.7};
  m.classes["Car"].fp_score_quantiles = {1, 4};
  const FpModel cell = fit_fp_cell(c.fit, sensor::KpiModel{}, 10, c.g, c.floor, 0);
  const sensor::KpiModel out = with_fp_table(m, cell);
  const auto& t = out.classes.at("Car").fp_table;
  ASSERT_TRUE(t.present());
  EXPECT_EQ(t.feature, "range");
  ASSERT_EQ(t.rate.size(), 3u);
  EXPECT_NEAR(t.edges[1], cell.cell[0], 1e-9);
  EXPECT_NEAR(t.edges[2], cell.cell[1], 1e-9);
  EXPECT_GT(t.rate[1], cell.cell_rate) << "the cell's bin: the cell plus the background there";
  const auto& aq = t.azimuth_quantiles[1];
  EXPECT_NEAR(aq[10], 0.5 * (cell.cell[2] + cell.cell[3]), 3 * fpcell_kDeg) << "the cell bin's median azimuth";
  double n = 0;
  for (const auto& r : c.fit.fps) n += r.cls == 0;
  EXPECT_NEAR(t.total_rate(), n / c.fit.frames.size(), 0.05);
}

// Uniform clutter (no hot spot, as on the campaign's controls): no rectangle is a cell. A rectangle
// over most of the field would fit the held-out counts a little better than the base's 21 noisy
// quantiles (a uniform placement), and passed as a cell on a control set before the hot-spot rule.
TEST(FpCellForm, UniformClutterHasNoCell) {
  for (unsigned seed : {21u, 22u, 23u}) {
    const ObjectSet fit = fpcell_set(300, seed, 0.0);
    const FpGrid g = fp_grid(fit);
    const FpData d = fp_data(fit, g);
    for (int cls : {-1, 0}) {
      const FpModel m = fit_fp_cell(d, sensor::KpiModel{}, 10, g, fp_floor(d, g.cells()), cls);
      EXPECT_LT(m.cell_rate, 0) << "seed " << seed << " class " << cls << ": a cell " << m.cell[0] << "-" << m.cell[1]
                                << " m x " << m.cell[2] / fpcell_kDeg << "-" << m.cell[3] / fpcell_kDeg << " deg";
    }
  }
}

// Weighted quantiles of a uniform stretch are its evenly spaced points.
TEST(FpCellForm, WeightedQuantilesOfAUniformStretch) {
  std::vector<std::pair<double, double>> v;
  for (int k = 0; k <= 1000; ++k) v.push_back({10 + 0.01 * k, 1.0});
  const auto q = weighted_quantiles(v);
  ASSERT_EQ(q.size(), 21u);
  for (int i = 0; i < 21; ++i) EXPECT_NEAR(q[i], 10 + 0.5 * i, 0.01);
  EXPECT_TRUE(weighted_quantiles({{1.0, 0.0}, {2.0, 0.0}}).empty());
}

// A dropout beyond 15 m where every range row beyond the edge is well held by the fit records: the
// cells there learn the dropout themselves, so a window [15, 20) fits exactly as well as the step.
// The step is the form (one edge fewer), and only it carries the gain to a row the fit split does not
// hold: an object at 35 m (row [30, inf), no fit records) must be predicted near 0.09, not at the
// class's rate.
TEST(FpCellRateGain, PrefersTheStepWhereAWindowsFarEdgeBuysNothing) {
  std::vector<double> x, y;
  std::vector<int> cls, cell;
  for (int row = 0; row < 3; ++row)
    for (int i = 0; i < 200; ++i) {
      const double r = 10 * row + 0.025 + 10.0 * i / 200;
      const double p = r < 15 ? 0.9 : 0.09;
      x.push_back(r), y.push_back(std::floor((i + 1) * p) - std::floor(i * p)), cls.push_back(0), cell.push_back(row);
    }
  sensor::KpiModel base;
  base.range_bin_edges = {0, 10, 20, 30};
  base.visibility_bin_edges = {0};
  const auto q = rate_gain_cells(y, std::vector<double>(y.size(), 1.0), cls, cell, 4, 1);
  base.classes["Car"].detection_probability = {{q[0][0]}, {q[0][1]}, {q[0][2]}, {q[0][3]}};
  const Refit f = fit_rate_gain(x, y, cls, cell, base, 1, 30, 30);
  ASSERT_TRUE(f.has_gain());
  const BinnedTable& g = f.gain.pooled;
  ASSERT_EQ(g.edges.size(), 1u) << "a step, not a window";
  EXPECT_NEAR(g.edges[0], 15, 0.5);
  const double p35 = refit_probability(f, 0, 3, 35.0, base.classes.at("Car").detection_probability[3][0]);
  EXPECT_LT(p35, 0.2) << "beyond the fit records, the gain still applies";
}
