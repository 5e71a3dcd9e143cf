// Lane fitting on polylines sampled from known cubics.
#include <gtest/gtest.h>

#include "sensor/lanes.h"

using namespace lidarsim::sensor;

TEST(Lanes, CubicFitRecoversKnownCoefficientsAndRange) {
  LanePolyline lane{4, LaneType::Solid, {}};
  for (double x = 5; x <= 80.0001; x += 0.5) lane.points.emplace_back(x, 1.5 + 0.02 * x - 4e-4 * x * x + 2e-6 * x * x * x, -1.7);
  LanePolynomial p;
  ASSERT_TRUE(fit_lane(lane, p));
  EXPECT_EQ(p.id, 4);
  EXPECT_NEAR(p.c0, 1.5, 1e-6);
  EXPECT_NEAR(p.c1, 0.02, 1e-7);
  EXPECT_NEAR(p.c2, -4e-4, 1e-9);
  EXPECT_NEAR(p.c3, 2e-6, 1e-11);
  EXPECT_DOUBLE_EQ(p.x_min, 5);
  EXPECT_NEAR(p.x_max, 80, 1e-9);
}

TEST(Lanes, NoisyPointsFitWithinNoise) {
  LanePolyline lane{1, LaneType::Dashed, {}};
  // Deterministic +-5 cm zig-zag "noise" around y = -3 + 0.01 x.
  int k = 0;
  for (double x = -20; x <= 40; x += 1, ++k) lane.points.emplace_back(x, -3 + 0.01 * x + ((k % 2) ? 0.05 : -0.05), 0);
  LanePolynomial p;
  ASSERT_TRUE(fit_lane(lane, p));
  for (double x = -20; x <= 40; x += 5) EXPECT_NEAR(evaluate(p, x), -3 + 0.01 * x, 0.02);
}

TEST(Lanes, TwoPointsGiveALineAndCrossingLaneIsSkipped) {
  LanePolynomial p;
  ASSERT_TRUE(fit_lane({1, LaneType::Solid, {{0, 1, 0}, {10, 3, 0}}}, p));
  EXPECT_NEAR(p.c0, 1, 1e-9);
  EXPECT_NEAR(p.c1, 0.2, 1e-9);
  EXPECT_NEAR(p.c2, 0, 1e-12);
  EXPECT_NEAR(p.c3, 0, 1e-12);
  // A marking across the view (x constant) is not a function y(x).
  EXPECT_FALSE(fit_lane({2, LaneType::Solid, {{20, -10, 0}, {20.5, 0, 0}, {20, 10, 0}}}, p));
  std::vector<LanePolynomial> out;
  fit_lanes({{1, LaneType::Solid, {{0, 1, 0}, {10, 3, 0}}}, {2, LaneType::Solid, {{20, -10, 0}, {20, 10, 0}}}}, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].id, 1);
}
