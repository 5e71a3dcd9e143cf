// The rate_gain form's edges (qualify/objects/object_rate_gain.h): each edge is a change point whose
// place is searched over, so it costs the log of the fit records, not half of it. A dropout beyond
// 15 m whose rate drifts further out (0.09 to 25 m, 0.15 from there: the mix of classes and
// visibility changes with range) is a step; with half the log a window to 21 m won on the drift,
// and a row the fit split does not hold (beyond 40 m) lost the gain.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_rate_gain.h"

using namespace lidarsim;
using namespace lidarsim::qualify;
using namespace lidarsim::qualify::obj;

namespace {

struct GainEdgesRecords {
  std::vector<double> x, y;
  std::vector<int> cls, cell;
};

// One class (Car), nvis 1; range rows of 10 m, the first four with 200 fit records each, the fifth
// (beyond 40 m) with none. Detected with a deterministic pattern of the given rate.
GainEdgesRecords gain_edges_drifting_dropout() {
  GainEdgesRecords r;
  for (int row = 0; row < 4; ++row)
    for (int i = 0; i < 200; ++i) {
      const double x = 10 * row + 0.025 + 10.0 * i / 200;
      const double p = x < 15 ? 0.9 : x < 25 ? 0.09 : 0.15;
      r.x.push_back(x), r.y.push_back(std::floor((i + 1) * p) - std::floor(i * p));
      r.cls.push_back(0), r.cell.push_back(row);
    }
  return r;
}

}  // namespace

TEST(RateGainEdges, ADropoutWhoseRateDriftsBeyondTheEdgeIsAStepAndCarriesItsGainPastTheFitRecords) {
  const GainEdgesRecords r = gain_edges_drifting_dropout();
  sensor::KpiModel base;
  base.range_bin_edges = {0, 10, 20, 30, 40};
  base.visibility_bin_edges = {0};
  const auto q = rate_gain_cells(r.y, std::vector<double>(r.y.size(), 1.0), r.cls, r.cell, 5, 1);
  base.classes["Car"].detection_probability = {{q[0][0]}, {q[0][1]}, {q[0][2]}, {q[0][3]}, {q[0][4]}};
  const Refit f = fit_rate_gain(r.x, r.y, r.cls, r.cell, base, 1, 40, 30);
  ASSERT_TRUE(f.has_gain());
  const BinnedTable& g = f.gain.pooled;
  ASSERT_EQ(g.edges.size(), 1u) << "a step, not a window with a far edge at "
                                << (g.edges.size() > 1 ? g.edges[1] : 0.0);
  EXPECT_NEAR(g.edges[0], 15, 0.5);
  EXPECT_LT(g.value[1], 0.2);
  const double p45 = refit_probability(f, 0, 4, 45.0, base.classes.at("Car").detection_probability[4][0]);
  EXPECT_LT(p45, 0.25) << "beyond the fit records the dropout goes on (the base gave " << q[0][4] << ")";
  EXPECT_GT(p45, 0.05);
}

// A dropout beyond 15.5 m, in the middle of one of the 40 equal-count bins (1 m each) the window is
// searched on: the edge is refined on bins 4 times finer, so the objects between 15 and 16 m are on
// the right side of it and the gain is the dropout's (found on the coarse bins alone: an edge at 15
// or 16 m, and a gain fitted against the row the objects share).
TEST(RateGainEdges, TheEdgeIsRefinedWithinTheBinItWasFoundIn) {
  GainEdgesRecords r;
  int i_before = 0, i_beyond = 0;
  for (int i = 0; i < 1600; ++i) {
    const double x = 0.0125 + 40.0 * i / 1600;
    const bool beyond = x >= 15.5;
    const double p = beyond ? 0.09 : 0.9;
    const int k = beyond ? i_beyond++ : i_before++;
    r.x.push_back(x), r.y.push_back(std::floor((k + 1) * p) - std::floor(k * p));
    r.cls.push_back(0), r.cell.push_back(static_cast<int>(x / 10));
  }
  sensor::KpiModel base;
  base.range_bin_edges = {0, 10, 20, 30};
  base.visibility_bin_edges = {0};
  const auto q = rate_gain_cells(r.y, std::vector<double>(r.y.size(), 1.0), r.cls, r.cell, 4, 1);
  base.classes["Car"].detection_probability = {{q[0][0]}, {q[0][1]}, {q[0][2]}, {q[0][3]}};
  const Refit f = fit_rate_gain(r.x, r.y, r.cls, r.cell, base, 1, 40, 30);
  ASSERT_TRUE(f.has_gain());
  const BinnedTable& g = f.gain.pooled;
  ASSERT_EQ(g.edges.size(), 1u);
  EXPECT_NEAR(g.edges[0], 15.5, 0.15) << "refined within the 1 m bin";
  EXPECT_NEAR(g.value[1], 0.1, 0.02) << "the gain beyond the edge";
  auto predicted = [&](double x) {
    const int row = static_cast<int>(x / 10);
    return refit_probability(f, 0, row, x, base.classes.at("Car").detection_probability[row][0]);
  };
  EXPECT_NEAR(predicted(15.2), 0.9, 0.05);
  EXPECT_NEAR(predicted(15.8), 0.09, 0.03);
}
