// Coordinate system manager on transforms worked out by hand.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "common/angles.h"
#include "sensor/frames.h"

using namespace lidarsim::sensor;
using lidarsim::kPi;

TEST(Frames, RpyRotationMatchesHandWorkedAxes) {
  // yaw 90 deg: x -> y; pitch 90 deg: x -> -z; roll 90 deg: y -> z.
  EXPECT_TRUE((rotation_from_rpy(0, 0, kPi / 2) * Eigen::Vector3d::UnitX()).isApprox(Eigen::Vector3d::UnitY(), 1e-12));
  EXPECT_TRUE((rotation_from_rpy(0, kPi / 2, 0) * Eigen::Vector3d::UnitX()).isApprox(-Eigen::Vector3d::UnitZ(), 1e-12));
  EXPECT_TRUE((rotation_from_rpy(kPi / 2, 0, 0) * Eigen::Vector3d::UnitY()).isApprox(Eigen::Vector3d::UnitZ(), 1e-12));
}

TEST(Frames, ComposeWithInverseIsIdentity) {
  const Pose p = make_pose({1, -2, 3}, 0.1, -0.2, 0.7);
  const Pose id = compose(p, inverse(p));
  EXPECT_TRUE(id.rotation.isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  EXPECT_LT(id.translation.norm(), 1e-12);
}

TEST(Frames, MapToEgoToSensorOnKnownTransform) {
  // Ego at (10, 5) heading 90 deg (facing +y of the map); sensor 1 m ahead, 2 m up, yawed
  // 90 deg left on the ego. An object at map (10, 15, 1) heading 180 deg, moving at map (-3, 0):
  //   ego frame:   10 m ahead -> (10, 0, 1), heading 90 deg, velocity (0, 3, 0);
  //   sensor frame: (10-1, 0, 1-2) rotated by -90 deg -> (0, -9, -1), heading 0,
  //   velocity (3, 0, 0).
  Frame map;
  map.ego_in_map = make_pose({10, 5, 0}, 0, 0, kPi / 2);
  Object o;
  o.id = 7;
  o.position = {10, 15, 1};
  o.velocity = {-3, 0, 0};
  o.acceleration = {0, 1, 0};
  o.heading = kPi;
  map.objects.push_back(o);
  map.lanes.push_back({3, LaneType::Dashed, {{10, 15, 0}, {11, 5, 0}}});

  Frame ego, sensor;
  map_to_ego(map, ego);
  ASSERT_EQ(ego.objects.size(), 1u);
  EXPECT_TRUE(ego.objects[0].position.isApprox(Eigen::Vector3d(10, 0, 1), 1e-12));
  EXPECT_NEAR(ego.objects[0].heading, kPi / 2, 1e-12);
  EXPECT_TRUE(ego.objects[0].velocity.isApprox(Eigen::Vector3d(0, 3, 0), 1e-12));
  EXPECT_TRUE(ego.objects[0].acceleration.isApprox(Eigen::Vector3d(1, 0, 0), 1e-12));
  EXPECT_TRUE(ego.lanes[0].points[1].isApprox(Eigen::Vector3d(0, -1, 0), 1e-12));

  const Pose mount = make_pose({1, 0, 2}, 0, 0, kPi / 2);
  ego_to_sensor(ego, mount, sensor);
  EXPECT_EQ(sensor.objects[0].id, 7);
  EXPECT_TRUE(sensor.objects[0].position.isApprox(Eigen::Vector3d(0, -9, -1), 1e-12));
  EXPECT_NEAR(sensor.objects[0].heading, 0, 1e-12);
  EXPECT_TRUE(sensor.objects[0].velocity.isApprox(Eigen::Vector3d(3, 0, 0), 1e-12));
  EXPECT_TRUE(sensor.lanes[0].points[0].isApprox(Eigen::Vector3d(0, -9, -2), 1e-12));
  EXPECT_EQ(sensor.lanes[0].type, LaneType::Dashed);
}

TEST(Frames, PitchedMountTiltsPointsDown) {
  // A sensor pitched 10 deg nose-down (positive pitch about y turns x towards -z) sees a point
  // straight ahead on its own height above the horizon by 10 deg.
  const Pose mount = make_pose({0, 0, 2}, 0, 10 * kPi / 180, 0);
  Frame ego, sensor;
  Object o;
  o.position = {20, 0, 2};
  ego.objects.push_back(o);
  ego_to_sensor(ego, mount, sensor);
  const auto& p = sensor.objects[0].position;
  EXPECT_NEAR(std::atan2(p.z(), p.x()), 10 * kPi / 180, 1e-12);
  EXPECT_NEAR(p.norm(), 20, 1e-12);
}

TEST(Frames, WrapPiIsTheRemainderBy2PiBitForBit) {
  // wrap_pi skips the call for |a| <= pi: it must give std::remainder's answer everywhere.
  constexpr double pi = std::numbers::pi;
  std::vector<double> angles = {0.0, -0.0, pi, -pi, std::nextafter(pi, 4.0), std::nextafter(-pi, -4.0),
                                2 * pi, -2 * pi, 3 * pi, -3 * pi, 1e-300, 1e300, -7.5, 100.25};
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-20, 20);
  for (int i = 0; i < 100000; ++i) angles.push_back(u(rng));
  for (double a : angles) {
    const double want = std::remainder(a, 2 * pi), got = wrap_pi(a);
    EXPECT_EQ(std::signbit(want), std::signbit(got)) << a;
    ASSERT_EQ(want, got) << a;
  }
  EXPECT_TRUE(std::isnan(wrap_pi(std::nan(""))));
}
