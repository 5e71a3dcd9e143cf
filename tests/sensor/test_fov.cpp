// Field of view: objects on and just outside each limit.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "common/angles.h"
#include "sensor/fov.h"

using namespace lidarsim::sensor;
using lidarsim::kDeg;

namespace {
// A 1 m cube whose centre is at (range, azimuth, elevation) in the sensor frame.
Object cube_at(double range, double az_deg, double el_deg) {
  Object o;
  o.size = {1, 1, 1};
  o.position = range * Eigen::Vector3d(std::cos(el_deg * kDeg) * std::cos(az_deg * kDeg),
                                       std::cos(el_deg * kDeg) * std::sin(az_deg * kDeg), std::sin(el_deg * kDeg));
  return o;
}
FieldOfView narrow() {
  FieldOfView f;
  f.azimuth_min = -30 * kDeg;
  f.azimuth_max = 60 * kDeg;
  f.elevation_min = -20 * kDeg;
  f.elevation_max = 10 * kDeg;
  f.range_min = 1;
  f.range_max = 50;
  return f;
}
}  // namespace

TEST(Fov, RangeLimitUsesTheBoxClosestPoint) {
  const FieldOfView f = narrow();
  // Centre 50.4 m away: its near face is at 49.9 m, inside the 50 m limit.
  EXPECT_TRUE(object_in_fov(cube_at(50.4, 0, 0), f));
  // Centre 50.6 m: the near face is at 50.1 m, just outside.
  EXPECT_FALSE(object_in_fov(cube_at(50.6, 0, 0), f));
}

TEST(Fov, MinimumRange) {
  FieldOfView f = narrow();
  f.range_min = 5;
  // Farthest corner of a cube at 3.5 m is about 4.1 m: entirely inside the blind zone.
  EXPECT_FALSE(object_in_fov(cube_at(3.5, 0, 0), f));
  EXPECT_TRUE(object_in_fov(cube_at(4.8, 0, 0), f));
}

TEST(Fov, HorizontalLimitsOnAndJustOutside) {
  const FieldOfView f = narrow();
  // At 20 m a 1 m cube seen at 60 deg spans about +-1.95 deg (its corners): centre 1 deg past the limit still
  // has a corner inside; 3 deg past it has none.
  EXPECT_TRUE(object_in_fov(cube_at(20, 60, 0), f));
  EXPECT_TRUE(object_in_fov(cube_at(20, 61, 0), f));
  EXPECT_FALSE(object_in_fov(cube_at(20, 63, 0), f));
  EXPECT_TRUE(object_in_fov(cube_at(20, -31, 0), f));
  EXPECT_FALSE(object_in_fov(cube_at(20, -33, 0), f));
}

TEST(Fov, VerticalLimitsOnAndJustOutside) {
  const FieldOfView f = narrow();
  EXPECT_TRUE(object_in_fov(cube_at(20, 0, 10), f));
  EXPECT_TRUE(object_in_fov(cube_at(20, 0, 11), f));
  EXPECT_FALSE(object_in_fov(cube_at(20, 0, 12.5), f));
  EXPECT_TRUE(object_in_fov(cube_at(20, 0, -21), f));
  EXPECT_FALSE(object_in_fov(cube_at(20, 0, -22.5), f));
}

TEST(Fov, BoxAcrossTheRearSeamAndSensorInsideBox) {
  FieldOfView f;  // full circle
  f.azimuth_min = 150 * kDeg;
  f.azimuth_max = 210 * kDeg;  // a rear-looking sensor whose view crosses +-180 deg
  EXPECT_TRUE(object_in_fov(cube_at(10, 180, 0), f));
  EXPECT_TRUE(object_in_fov(cube_at(10, -170, 0), f));
  EXPECT_FALSE(object_in_fov(cube_at(10, 0, 0), f));
  Object big;
  big.size = {10, 10, 10};
  EXPECT_TRUE(object_in_fov(big, f));  // the sensor sits inside it
}

TEST(Fov, ApplyRemovesOnlyOutsideObjectsAndTrimsLanes) {
  const FieldOfView f = narrow();
  std::vector<Object> objs = {cube_at(10, 0, 0), cube_at(10, 90, 0), cube_at(80, 0, 0)};
  objs[0].id = 1;
  EXPECT_EQ(apply_fov(objs, f), 2);
  ASSERT_EQ(objs.size(), 1u);
  EXPECT_EQ(objs[0].id, 1);
  std::vector<LanePolyline> lanes = {{1, LaneType::Solid, {}}};
  for (double x = 0; x <= 100; x += 1) lanes[0].points.emplace_back(x, 2, -1.7);
  apply_fov_to_lanes(lanes, f);
  ASSERT_EQ(lanes.size(), 1u);
  // Kept: range within [1, 50] and elevation above -20 deg (x >= 1.7/tan(20 deg) = 4.67 m).
  EXPECT_NEAR(lanes[0].points.front().x(), 5, 1e-12);
  EXPECT_NEAR(lanes[0].points.back().x(), 49, 1e-12);
}

// --- Truncation: share of the corners' (azimuth, elevation) rectangle outside the FoV ---

namespace {
// A cube of side s whose centre is at (range, azimuth) in the horizontal plane, its heading along
// the line of sight: its corners span the centre azimuth +- atan(s/2 / (range - s/2)) exactly
// (the nearer face's corners) and elevations symmetric about 0.
Object aligned_cube(double range, double az_deg, double s = 1) {
  Object o = cube_at(range, az_deg, 0);
  o.size = {s, s, s};
  o.heading = az_deg * kDeg;
  return o;
}
double half_span(double range, double s = 1) { return std::atan(s / 2 / (range - s / 2)); }
FieldOfView wide_vertical(double az_min_deg, double az_max_deg) {
  FieldOfView f;
  f.azimuth_min = az_min_deg * kDeg;
  f.azimuth_max = az_max_deg * kDeg;
  return f;
}
}  // namespace

TEST(FovTruncation, FullyInsideIsZeroAndFullCircleIsZero) {
  EXPECT_EQ(fov_truncation(aligned_cube(20, 0), narrow()), 0);
  EXPECT_EQ(fov_truncation(cube_at(20, 17, -5), narrow()), 0) << "any heading, well inside";
  EXPECT_EQ(fov_truncation(aligned_cube(3, 180), FieldOfView{}), 0) << "default FoV: the whole sphere";
}

TEST(FovTruncation, BoxStraddlingTheAzimuthLimitSymmetricallyIsHalfOut) {
  EXPECT_NEAR(fov_truncation(aligned_cube(20, 60), narrow()), 0.5, 1e-12) << "left limit 60 deg";
  EXPECT_NEAR(fov_truncation(aligned_cube(20, -30), narrow()), 0.5, 1e-12) << "right limit -30 deg";
}

TEST(FovTruncation, BoxMostlyOutsideIsCloseToOne) {
  // Centre 0.8 half-spans past the 60 deg limit: inside is (1 - 0.8) / 2 = 0.1 of the span.
  const double h = half_span(20);
  const Object o = aligned_cube(20, 60 + 0.8 * h / kDeg);
  EXPECT_NEAR(fov_truncation(o, narrow()), 0.9, 1e-9);
  // apply_fov keeps it (a corner is in view) and records the share.
  std::vector<Object> objs = {o, aligned_cube(20, 0)};
  EXPECT_EQ(apply_fov(objs, narrow()), 0);
  ASSERT_EQ(objs.size(), 2u);
  EXPECT_NEAR(objs[0].truncation, 0.9, 1e-9);
  EXPECT_EQ(objs[1].truncation, 0);
}

TEST(FovTruncation, ElevationLimitAndBothLimitsMultiplyAsAreas) {
  FieldOfView f = wide_vertical(-30, 60);
  f.elevation_max = 0;  // the cube's upper half is above the view
  EXPECT_NEAR(fov_truncation(aligned_cube(20, 0), f), 0.5, 1e-12);
  // Half out in azimuth and half out in elevation: a quarter of the rectangle is inside.
  EXPECT_NEAR(fov_truncation(aligned_cube(20, 60), f), 0.75, 1e-12);
}

TEST(FovTruncation, AcrossTheRearSeam) {
  // A rear-looking FoV given beyond +-180 deg: a cube straddling the seam is inside; one centred
  // on its 90 deg limit is half out.
  EXPECT_NEAR(fov_truncation(aligned_cube(3, 180), wide_vertical(90, 270)), 0, 1e-12);
  EXPECT_NEAR(fov_truncation(aligned_cube(3, 90), wide_vertical(90, 270)), 0.5, 1e-12);
  // A FoV with a 20 deg gap behind ([-170, 170] deg) and a close cube behind spanning +-11.3 deg:
  // its two ends (past 170 and past -170 deg) are in view, 10 deg of each half-span is not.
  const double h = half_span(3);
  ASSERT_GT(h, 10 * kDeg);
  EXPECT_NEAR(fov_truncation(aligned_cube(3, 180), wide_vertical(-170, 170)), 10 * kDeg / h, 1e-12);
  EXPECT_NEAR(fov_truncation(aligned_cube(3, -180), wide_vertical(-170, 170)), 10 * kDeg / h, 1e-12);
}

TEST(FovTruncation, BoxAroundTheSensorSpansEveryDirection) {
  Object big;  // the sensor at its centre: every azimuth, elevation -90..90 deg
  big.size = {4, 2, 2};
  EXPECT_NEAR(fov_truncation(big, wide_vertical(-90, 90)), 0.5, 1e-12);
  FieldOfView f = wide_vertical(-90, 90);
  f.elevation_max = 0;
  EXPECT_NEAR(fov_truncation(big, f), 0.75, 1e-12);
}
