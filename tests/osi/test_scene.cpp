// A scene worked out by hand, run through the OSI interface and the whole sensor model (ideal
// KPI manager, so positions are the tracker's): the host (id 99) stands at the origin with the
// sensor 1.73 m above the road; a van (11) 15 m ahead in plain view; a car (12) 25 m ahead
// behind the van; a pedestrian (13) crossing from the left 10 m ahead at 1.5 m/s; a solid lane
// boundary (500) 3 m to the right.
//
// Worked out: the van's near face is 11.5 m from the sensor and its top 0.47 m above the sensor,
// i.e. it covers azimuths within +-5.0 deg (1 m / 11.5 m) and elevations up to +2.3 deg; the car
// behind (near face 21.75 m away) spans at most +-2.4 deg and its top is 0.23 m below the sensor
// (-0.6 deg), so it is hidden entirely.
// The pedestrian is at azimuth 28 deg, clear of the van. Tracks confirm on their second frame,
// so the third SensorData must hold exactly the van and the pedestrian.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <string>

#include "common/angles.h"
#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"

namespace {

using lidarsim::kPi;

void scene_add_object(osi3::GroundTruth& gt, std::uint64_t id, osi3::MovingObject::Type type, double x, double y, double z,
                double l, double w, double h, double vy = 0) {
  auto* o = gt.add_moving_object();
  o->mutable_id()->set_value(id);
  o->set_type(type);
  if (type == osi3::MovingObject::TYPE_VEHICLE)
    o->mutable_vehicle_classification()->set_type(id == 11 ? osi3::MovingObject::VehicleClassification::TYPE_DELIVERY_VAN
                                                           : osi3::MovingObject::VehicleClassification::TYPE_MEDIUM_CAR);
  auto* b = o->mutable_base();
  b->mutable_position()->set_x(x);
  b->mutable_position()->set_y(y);
  b->mutable_position()->set_z(z);
  b->mutable_dimension()->set_length(l);
  b->mutable_dimension()->set_width(w);
  b->mutable_dimension()->set_height(h);
  b->mutable_orientation()->set_yaw(0);
  b->mutable_velocity()->set_y(vy);
}

osi3::SensorView scene_frame_at(double t) {
  osi3::SensorView v;
  v.mutable_timestamp()->set_seconds(static_cast<std::int64_t>(std::floor(t)));
  v.mutable_timestamp()->set_nanos(static_cast<std::uint32_t>(std::lround((t - std::floor(t)) * 1e9)));
  v.mutable_sensor_id()->set_value(7);
  v.mutable_host_vehicle_id()->set_value(99);
  v.mutable_mounting_position()->mutable_position()->set_x(1.0);   // 1 m ahead of the rear axle,
  v.mutable_mounting_position()->mutable_position()->set_z(1.43);  // which is 0.3 m above the road
  auto& gt = *v.mutable_global_ground_truth();
  scene_add_object(gt, 99, osi3::MovingObject::TYPE_VEHICLE, 1.4, 0, 0.75, 4.5, 1.8, 1.5);
  auto* r = gt.mutable_moving_object(0)->mutable_vehicle_attributes()->mutable_bbcenter_to_rear();
  r->set_x(-1.4);
  r->set_z(-0.45);
  scene_add_object(gt, 11, osi3::MovingObject::TYPE_VEHICLE, 15, 0, 1.1, 5, 2, 2.2);
  scene_add_object(gt, 12, osi3::MovingObject::TYPE_VEHICLE, 25, 0, 0.75, 4.5, 1.8, 1.5);
  scene_add_object(gt, 13, osi3::MovingObject::TYPE_PEDESTRIAN, 10, 5 - 1.5 * t, 0.9, 0.6, 0.6, 1.8, -1.5);
  auto* lane = gt.add_lane_boundary();
  lane->mutable_id()->set_value(500);
  lane->mutable_classification()->set_type(osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
  for (double x : {-10.0, 60.0}) {
    auto* p = lane->add_boundary_line()->mutable_position();
    p->set_x(x);
    p->set_y(-3);
  }
  return v;
}

}  // namespace

TEST(OsiScene, PlainViewVanAndCrossingPedestrianReportedHiddenCarAndHostAbsent) {
  using namespace lidarsim;
  const std::string src = LIDARSIM_SOURCE_DIR;
  infer::SimOptions options;
  options.kpi.noise = options.kpi.misses = options.kpi.false_positives = options.kpi.flips = false;
  auto runner = infer::OsiRunner::from_files(src + "/data/scenarios/demo_urban.json",
                                             src + "/data/models/kpi_pointrcnn.json",
                                             src + "/data/models/intensity_unet.h5", options);
  osi3::SensorData out;
  for (int k = 0; k < 3; ++k) runner.step(scene_frame_at(0.1 * k), k, "hand", out);

  EXPECT_EQ(out.version().version_major(), 3u);
  EXPECT_EQ(out.timestamp().nanos(), 200000000u);
  EXPECT_EQ(out.sensor_id().value(), 7u);
  EXPECT_DOUBLE_EQ(out.mounting_position().position().z(), 1.43);

  std::map<std::uint64_t, const osi3::DetectedMovingObject*> by_truth;
  for (const auto& m : out.moving_object()) {
    ASSERT_EQ(m.header().ground_truth_id_size(), 1);
    by_truth[m.header().ground_truth_id(0).value()] = &m;
  }
  ASSERT_EQ(by_truth.size(), 2u);
  ASSERT_TRUE(by_truth.count(11));
  ASSERT_TRUE(by_truth.count(13));
  const auto& van = *by_truth[11];
  EXPECT_NEAR(van.base().position().x(), 14.0, 0.05);  // sensor 1 m ahead of the rear axle
  EXPECT_NEAR(van.base().position().y(), 0.0, 0.05);
  EXPECT_NEAR(van.base().position().z(), 1.1 - 1.73, 0.05);
  EXPECT_NEAR(van.base().dimension().length(), 5.0, 1e-9);
  EXPECT_NEAR(van.base().dimension().height(), 2.2, 1e-9);
  EXPECT_NEAR(van.base().velocity().x(), 0.0, 0.1);
  EXPECT_EQ(van.candidate(0).type(), osi3::MovingObject::TYPE_VEHICLE);
  EXPECT_EQ(van.candidate(0).vehicle_classification().type(),
            osi3::MovingObject::VehicleClassification::TYPE_DELIVERY_VAN);
  EXPECT_GE(van.header().existence_probability(), 0.0);
  EXPECT_LE(van.header().existence_probability(), 1.0);
  const auto& ped = *by_truth[13];
  EXPECT_NEAR(ped.base().position().x(), 9.0, 0.1);
  EXPECT_NEAR(ped.base().position().y(), 4.7, 0.25);  // the tracker trails a moving target a little
  EXPECT_LT(ped.base().velocity().y(), -0.5);
  EXPECT_EQ(ped.candidate(0).type(), osi3::MovingObject::TYPE_PEDESTRIAN);

  // Point cloud: returns on the van and the pedestrian, none on the hidden car or the host.
  ASSERT_EQ(out.feature_data().lidar_sensor_size(), 1);
  std::map<std::uint64_t, int> hits;
  for (const auto& d : out.feature_data().lidar_sensor(0).detection()) {
    ++hits[d.object_id().value()];
    EXPECT_GE(d.intensity(), 0.0);
    EXPECT_LE(d.intensity(), 100.0);
    if (d.object_id().value() == 11) {
      EXPECT_LT(std::abs(d.position().azimuth()), 5.05 * kPi / 180);
      EXPECT_GT(d.position().distance(), 11.45);
      EXPECT_LT(d.position().elevation(), 2.4 * kPi / 180);
    }
  }
  EXPECT_GT(hits[11], 100);
  EXPECT_GT(hits[13], 5);
  EXPECT_EQ(hits.count(12), 0u);
  EXPECT_EQ(hits.count(99), 0u);
  EXPECT_GT(hits[osi::kNoObject], 1000);  // the road
  EXPECT_EQ(out.feature_data().lidar_sensor(0).header().number_of_valid_detections(),
            static_cast<std::uint32_t>(out.feature_data().lidar_sensor(0).detection_size()));

  // The lane boundary 3 m to the right, in the sensor frame.
  ASSERT_GE(out.lane_boundary_size(), 1);
  bool found = false;
  for (const auto& l : out.lane_boundary()) {
    if (l.header().ground_truth_id_size() == 0 || l.header().ground_truth_id(0).value() != 500) continue;
    found = true;
    EXPECT_EQ(l.candidate(0).classification().type(), osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
    ASSERT_GE(l.boundary_line_size(), 2);
    for (const auto& p : l.boundary_line()) EXPECT_NEAR(p.position().y(), -3.0, 0.05);
  }
  EXPECT_TRUE(found);
}

TEST(OsiScene, TimestampThatDoesNotAdvanceIsAnErrorNamingTheMessage) {
  using namespace lidarsim;
  const std::string src = LIDARSIM_SOURCE_DIR;
  infer::SimOptions options;
  options.point_cloud = false;
  auto runner = infer::OsiRunner::from_files(src + "/data/scenarios/demo_urban.json",
                                             src + "/data/models/kpi_pointrcnn.json", "", options);
  osi3::SensorData out;
  runner.step(scene_frame_at(0.1), 0, "hand", out);
  try {
    runner.step(scene_frame_at(0.1), 1, "hand", out);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("hand: message 1: timestamp: does not advance"), std::string::npos) << e.what();
  }
}
