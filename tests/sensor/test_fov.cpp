// Field of view: objects on and just outside each limit.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "sensor/fov.h"

using namespace lidarsim::sensor;
constexpr double kDeg = std::numbers::pi / 180;

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
