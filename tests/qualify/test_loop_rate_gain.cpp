// The rate_gain form of a detection candidate (qualify/objects/object_rate_gain.h): a gain on the
// cell's probability inside a window of a feature, the cells refitted with it by the base model's
// own rule. Worked by hand on one class: detection 0.9 below 15 m and 0.09 beyond (a dropout x 0.1),
// range rows [0, 10), [10, 20), [20, inf) with 400, 400 and 10 objects. The base rule gives the
// last row (10 objects, fewer than kDetectionPriorObjects) the class's overall rate, mostly made of
// detections before the edge (0.45 against 0.09); the gain form must give it the class's rate x the
// gain: (1 + 15 x 0.90) / (10 x 0.1 + 15) x 0.1 = 0.09.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_rate_gain.h"
#include "sensor/kpi_fit.h"

using namespace lidarsim;
using namespace lidarsim::qualify;
using namespace lidarsim::qualify::obj;

namespace {

// Every `every`-th of n objects detected when p = 1 / every would be exact; here a deterministic
// pattern with the given rate (the running count rounds down).
double pattern(int i, double rate) { return std::floor((i + 1) * rate) - std::floor(i * rate); }

struct Records {
  std::vector<double> x, y;
  std::vector<int> cls, cell;
};

// One class (Car), nvis 1, rows [0, 10), [10, 20), [20, inf): cell = row.
Records dropout_beyond_15m() {
  Records r;
  auto add = [&](double x, int row, double y) { r.x.push_back(x), r.y.push_back(y), r.cls.push_back(0), r.cell.push_back(row); };
  for (int i = 0; i < 400; ++i) add(0.5 + 9.0 * i / 400, 0, pattern(i, 0.9));
  for (int i = 0; i < 200; ++i) add(10.2 + 4.6 * i / 200, 1, pattern(i, 0.9));    // [10.2, 14.8): before the edge
  for (int i = 0; i < 200; ++i) add(15.2 + 4.6 * i / 200, 1, pattern(i, 0.09));   // [15.2, 19.8): beyond it
  for (int i = 0; i < 10; ++i) add(21.0 + 3.0 * i, 2, pattern(i + 3, 0.09));     // 10 objects, none or one detected
  return r;
}

sensor::KpiModel car_base(const Records& r) {
  sensor::KpiModel m;
  m.range_bin_edges = {0, 10, 20};
  m.visibility_bin_edges = {0};
  const auto q = rate_gain_cells(r.y, std::vector<double>(r.y.size(), 1.0), r.cls, r.cell, 3, 1);
  m.classes["Car"].detection_probability = {{q[0][0]}, {q[0][1]}, {q[0][2]}};
  return m;
}

}  // namespace

// With gain 1 the cells are the base model's rule (sensor/kpi_fit.cpp): a row of >= 15 objects its
// own rate (one visibility cell: the row prior is the row's rate), a row of fewer the class's overall.
TEST(DetectionRateGain, AtGainOneTheCellsAreTheBaseRuleAndASparseRowTakesTheClassRate) {
  const Records r = dropout_beyond_15m();
  const auto q = rate_gain_cells(r.y, std::vector<double>(r.y.size(), 1.0), r.cls, r.cell, 3, 1);
  double hits = 0, row1 = 0;
  for (size_t i = 0; i < r.y.size(); ++i) hits += r.y[i], row1 += r.cell[i] == 1 ? r.y[i] : 0;
  EXPECT_NEAR(q[0][0], 0.9, 1e-9);
  EXPECT_NEAR(q[0][1], row1 / 400, 1e-9);
  EXPECT_NEAR(q[0][2], (1 + 15 * hits / 810) / (10 + 15), 1e-9) << "10 objects, 1 detected, shrunk to the class rate";
  EXPECT_GT(q[0][2], 0.4) << "the base's sparse row beyond the edge: far above the true 0.09";
}

// The joint fit finds the edge and the gain, and puts the sparse row at the class's rate x the gain.
TEST(DetectionRateGain, FitsTheEdgeAndTheGainAndPredictsTheSparseRowBeyondTheEdge) {
  const Records r = dropout_beyond_15m();
  const sensor::KpiModel base = car_base(r);
  const Refit f = fit_rate_gain(r.x, r.y, r.cls, r.cell, base, 1, 40, 30);
  ASSERT_TRUE(f.has_gain());
  const BinnedTable& g = f.gain.pooled;
  ASSERT_EQ(g.edges.size(), 1u) << "a step (the window reaches the end)";
  EXPECT_NEAR(g.edges[0], 15, 0.5);
  EXPECT_NEAR(g.value[1], 0.1, 0.03) << "the gain beyond the edge";
  const double base_far = base.classes.at("Car").detection_probability[2][0];
  auto predicted = [&](double x, int row) {
    return refit_probability(f, 0, row, x, base.classes.at("Car").detection_probability[row][0]);
  };
  EXPECT_NEAR(predicted(5, 0), 0.9, 0.02);
  EXPECT_NEAR(predicted(12, 1), 0.9, 0.03);
  EXPECT_NEAR(predicted(17, 1), 0.09, 0.03);
  EXPECT_NEAR(predicted(30, 2), 0.09, 0.03) << "the base gave it " << base_far;
}

// Written into the KPI model: the cells refitted and the gain as the detection term's scale.
TEST(DetectionRateGain, WithTermWritesTheCellsAndTheGainAsTheDetectionScale) {
  const Records r = dropout_beyond_15m();
  const sensor::KpiModel base = car_base(r);
  const Refit f = fit_rate_gain(r.x, r.y, r.cls, r.cell, base, 1, 40, 30);
  const sensor::KpiModel m = with_term(base, f, kDetectionTarget, "range", 1);
  const sensor::ConditionalTerm& ct = m.classes.at("Car").detection_conditional;
  ASSERT_EQ(ct.scale.size(), 2u);
  EXPECT_EQ(ct.bias, (std::vector<double>{0, 0}));
  EXPECT_NEAR(ct.edges[1], f.gain.pooled.edges[0], 1e-12);
  EXPECT_NEAR(ct.scale[1], f.gain.pooled.value[1], 1e-12);
  const auto& dp = m.classes.at("Car").detection_probability;
  EXPECT_NEAR(dp[2][0] * ct.scale[1], refit_probability(f, 0, 2, 30, base.classes.at("Car").detection_probability[2][0]),
              1e-9);
}
