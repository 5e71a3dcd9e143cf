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
  ASSERT_EQ(g.edges.size(), 1u) << "a step, not a window with a far edge at " << (g.edges.size() > 1 ? g.edges[1] : 0.0);
  EXPECT_NEAR(g.edges[0], 15, 0.5);
  EXPECT_LT(g.value[1], 0.2);
  const double p45 = refit_probability(f, 0, 4, 45.0, base.classes.at("Car").detection_probability[4][0]);
  EXPECT_LT(p45, 0.25) << "beyond the fit records the dropout goes on (the base gave " << q[0][4] << ")";
  EXPECT_GT(p45, 0.05);
}
