#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>

#include "common/angles.h"
#include "common/error.h"
#include "pgm/materials.h"
#include "pgm/projection.h"

using namespace lidarsim::pgm;
using lidarsim::kPi;

namespace {
Point at(double range, double el_deg, double az_rad, float intensity = 0, int cls = 0) {
  const double el = el_deg * kPi / 180;
  Point p;
  p.x = static_cast<float>(range * std::cos(el) * std::cos(az_rad));
  p.y = static_cast<float>(range * std::cos(el) * std::sin(az_rad));
  p.z = static_cast<float>(range * std::sin(el));
  p.intensity = intensity;
  p.class_id = cls;
  return p;
}

// A scan in firing order: `rows` rings, each sweeping azimuth from ~0 up to ~2pi.
std::vector<Point> rings(const BeamLayout& l, int per_ring, double range = 10) {
  std::vector<Point> pts;
  for (int r = 0; r < l.rows(); ++r)
    for (int k = 0; k < per_ring; ++k)
      pts.push_back(at(range, l.elevations_rad[r] * 180 / kPi, (k + 0.3) * 2 * kPi / per_ring, float(r)));
  return pts;
}
}  // namespace

TEST(Projection, NearestReturnWinsTheCellAndLoserStillGetsItsValueBack) {
  const auto l = BeamLayout::uniform(2, 1, -1, 16);
  std::vector<Point> pts = {at(20, 1, 0.1, 0.9f, cls::building), at(5, 1, 0.12, 0.2f, cls::car)};
  ProjectOptions o;
  o.row_mode = RowMode::NearestElevation;
  const auto res = project(pts, l, o);
  const auto& m = res.pgm;
  EXPECT_EQ(m.point_index()[0], 1);  // the nearer point
  EXPECT_NEAR(m.at(m.channel_index("range"), 0, 0), 5, 1e-4);
  EXPECT_EQ(m.at(m.channel_index("class"), 0, 0), float(cls::car));
  EXPECT_EQ(m.at(m.channel_index("intensity"), 0, 0), 0.2f);
  EXPECT_EQ(m.at(m.channel_index("mask"), 0, 0), 1.f);
  EXPECT_EQ(m.at(m.channel_index("mask"), 1, 0), 0.f);
  // Back-projection: both points, including the one that lost the cell, get the cell's value.
  std::vector<float> pred(m.cells(), 0.f);
  pred[0] = 0.42f;
  const auto back = back_project(pred.data(), res.point_cell);
  EXPECT_EQ(back[0], 0.42f);
  EXPECT_EQ(back[1], 0.42f);
}

TEST(Projection, FiringOrderCutGivesRowPerRingEvenWithStragglersAtTheWrap) {
  const auto l = BeamLayout::uniform(8, 2, -20, 256);
  auto pts = rings(l, 300);
  // Stragglers: a point measured just before the wrap stored just after it (azimuth ~2pi right
  // after the jump to ~0), on rows 3 and 5.
  for (int r : {3, 5}) {
    auto pos = pts.begin() + r * 300 + 1;
    pts.insert(pos, at(10, l.elevations_rad[r] * 180 / kPi, 2 * kPi - 0.001, float(r)));
  }
  std::vector<int> rows;
  EXPECT_EQ(firing_order_rows(pts, rows), 8);
  const auto res = project(pts, l);
  EXPECT_EQ(res.row_mode, RowMode::FiringOrder);
  const auto& m = res.pgm;
  // Intensity carries the true ring: every filled cell's ring equals its row.
  for (int r = 0; r < 8; ++r) {
    for (int c = 0; c < 256; ++c) {
      if (m.at(m.channel_index("mask"), r, c) > 0) {
        EXPECT_EQ(m.at(m.channel_index("intensity"), r, c), float(r));
      }
    }
  }
}

TEST(Projection, ShuffledCloudFallsBackToNearestElevation) {
  const auto l = BeamLayout::uniform(8, 2, -20, 256);
  auto pts = rings(l, 300);
  std::mt19937 rng(7);
  std::shuffle(pts.begin(), pts.end(), rng);
  const auto res = project(pts, l);
  EXPECT_EQ(res.row_mode, RowMode::NearestElevation);
  const auto& m = res.pgm;
  int filled = 0;
  for (int r = 0; r < 8; ++r)
    for (int c = 0; c < 256; ++c)
      if (m.at(m.channel_index("mask"), r, c) > 0) {
        ++filled;
        EXPECT_EQ(m.at(m.channel_index("intensity"), r, c), float(r));
      }
  EXPECT_EQ(filled, 8 * 256);
  ProjectOptions strict;
  strict.row_mode = RowMode::FiringOrder;
  EXPECT_THROW(project(pts, l, strict), lidarsim::Error);
}

TEST(Projection, RingIndexIsUsedWhenEveryPointHasOne) {
  const auto l = BeamLayout::uniform(4, 2, -2, 64);
  std::vector<Point> pts = {at(10, 2, 0.5), at(10, 2, 0.6)};
  pts[0].ring = 3;  // ring disagrees with elevation: the recorded ring wins
  pts[1].ring = 0;
  const auto res = project(pts, l);
  EXPECT_EQ(res.row_mode, RowMode::Ring);
  EXPECT_EQ(res.point_cell[0] / 64, 3);
}

TEST(Projection, NonFinitePointIsAnErrorNamingSourceAndPoint) {
  const auto l = BeamLayout::uniform(2, 1, -1, 16);
  std::vector<Point> pts = {at(5, 0, 0), at(5, 0, 1)};
  pts[1].y = NAN;
  try {
    project(pts, l, {}, "scan.bin");
    FAIL();
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("scan.bin: point 1"), std::string::npos) << e.what();
  }
}

TEST(Projection, EffectChannelsHoldGeometry) {
  const auto l = BeamLayout::uniform(3, 2, -2, 64);
  ProjectOptions o;
  o.extra_channels = {"elevation", "azimuth", "height"};
  o.row_mode = RowMode::NearestElevation;
  const auto res = project({at(10, -2, 1.0)}, l, o);
  const auto& m = res.pgm;
  const int col = l.column_of(std::cos(1.0), std::sin(1.0));
  EXPECT_NEAR(m.at(m.channel_index("elevation"), 2, col), -2 * kPi / 180, 1e-5);
  EXPECT_NEAR(m.at(m.channel_index("azimuth"), 2, col), 1.0, 1e-5);
  EXPECT_NEAR(m.at(m.channel_index("height"), 2, col), 10 * std::sin(-2 * kPi / 180), 1e-4);
}

TEST(Projection, IncidenceIsNearZeroHeadOnAndLargeOnGrazingGround) {
  // A wall perpendicular to x at 10 m, seen head-on around column 0.
  const auto l = BeamLayout::uniform(9, 4, -4, 360);
  PolarGridMap wall(l, {"range", "mask"});
  PolarGridMap ground(l, {"range", "mask"});
  for (int r = 0; r < l.rows(); ++r)
    for (int c = 0; c < l.columns; ++c) {
      const double az = l.azimuth_of_column(c), el = l.elevations_rad[r];
      if (std::cos(az) > 0.5) wall.at(0, r, c) = static_cast<float>(10 / (std::cos(el) * std::cos(az)));
      if (el < 0) ground.at(0, r, c) = static_cast<float>(1.7 / std::sin(-el));  // flat ground 1.7 m below
    }
  compute_incidence(wall);
  compute_incidence(ground);
  EXPECT_LT(wall.at(wall.channel_index("incidence"), 4, 0), 0.02);
  // Ground at -4 deg elevation: incidence = 90 - 4 = 86 deg.
  EXPECT_NEAR(ground.at(ground.channel_index("incidence"), 8, 100), (90 - 4) * kPi / 180, 0.02);
}

TEST(Projection, IncidenceFromProjectedGroundPointsMatchesGeometry) {
  // Flat ground 1.7 m below the sensor, one point per beam/column on the beams that hit it.
  const auto l = BeamLayout::uniform(9, -4, -12, 360);
  std::vector<Point> pts;
  for (int r = 0; r < l.rows(); ++r)
    for (int c = 0; c < l.columns; ++c) {
      const double el = l.elevations_rad[r], az = l.azimuth_of_column(c), d = 1.7 / std::tan(-el);
      Point p;
      p.x = float(d * std::cos(az)), p.y = float(d * std::sin(az)), p.z = -1.7f;
      pts.push_back(p);
    }
  ProjectOptions o;
  o.extra_channels = {"incidence"};
  const auto res = project(pts, l, o);
  const auto& m = res.pgm;
  // Incidence on flat ground = 90 deg - |elevation|: 82 deg on the -8 deg row (row 4).
  EXPECT_NEAR(m.at(m.channel_index("incidence"), 4, 50), (90 - 8) * kPi / 180, 0.01);
  EXPECT_NEAR(m.at(m.channel_index("incidence"), 0, 200), (90 - 4) * kPi / 180, 0.01);
}

TEST(Projection, DepthDiscontinuityFlagsBothSidesOfAnOcclusionEdgeOnly) {
  // One ring: a wall at 20 m, a pole at 5 m in columns 10..12, no return in column 30; columns wrap.
  const auto l = BeamLayout::uniform(1, 0, 0, 64);
  std::vector<Point> pts;
  for (int c = 0; c < l.columns; ++c) {
    if (c == 30) continue;
    const double range = c >= 10 && c <= 12 ? 5.0 : 20.0 + 0.01 * c;  // a gentle slope is no edge
    pts.push_back(at(range, 0, l.azimuth_of_column(c)));
  }
  ProjectOptions o;
  o.extra_channels = {"depth_discontinuity"};
  o.row_mode = RowMode::NearestElevation;
  const auto res = project(pts, l, o);
  const int ch = res.pgm.channel_index("depth_discontinuity");
  for (int c = 0; c < l.columns; ++c) {
    const bool edge = c == 9 || c == 10 || c == 12 || c == 13;
    EXPECT_EQ(res.pgm.at(ch, 0, c), edge ? 1.f : 0.f) << "column " << c;  // 29, 31: next to no return, not an edge
  }
  // The same from the range channel alone (simulated grids).
  PolarGridMap sim(l, {"range", "mask"});
  for (int c = 0; c < l.columns; ++c) sim.at(0, 0, c) = res.pgm.at(res.pgm.channel_index("range"), 0, c);
  compute_depth_discontinuity(sim);
  for (int c = 0; c < l.columns; ++c)
    EXPECT_EQ(sim.at(sim.channel_index("depth_discontinuity"), 0, c), res.pgm.at(ch, 0, c)) << "column " << c;
}
