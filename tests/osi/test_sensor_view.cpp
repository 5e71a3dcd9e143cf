// SensorView -> scene: OSI's host vehicle frame (rear-axle centre) and our ego frame (road point
// below it) line up, the host is dropped, classes and ids map both ways.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>

#include "common/error.h"
#include "osi/scenario_trace.h"
#include "osi/sensor_view.h"
#include "pgm/materials.h"
#include "sensor/frames.h"
#include "sensor/scenario.h"

namespace {

const lidarsim::sensor::Scenario& demo() {
  static const auto s =
      lidarsim::sensor::read_scenario(std::string(LIDARSIM_SOURCE_DIR) + "/data/scenarios/demo_urban.json");
  return s;
}

}  // namespace

TEST(OsiSensorView, ScenarioThroughOsiGivesBackTheSameEgoMountObjectsAndLanes) {
  using namespace lidarsim;
  const double t = 2.3;
  osi3::SensorView v;
  osi::sensor_view_from_scenario(demo(), t, v);
  osi::IdMap ids;
  osi::SceneFrame scene;
  osi::scene_from_sensor_view(v, 0, "demo", ids, scene);
  sensor::Frame truth;
  sensor::sample_frame(demo(), t, truth);

  EXPECT_NEAR(scene.time, t, 1e-9);
  EXPECT_LT((scene.map.ego_in_map.translation - truth.ego_in_map.translation).norm(), 1e-9);
  EXPECT_LT((scene.map.ego_in_map.rotation - truth.ego_in_map.rotation).norm(), 1e-9);
  EXPECT_LT((scene.mount.translation - demo().sensor.mount.translation).norm(), 1e-9);
  EXPECT_LT((scene.mount.rotation - demo().sensor.mount.rotation).norm(), 1e-9);
  ASSERT_EQ(scene.map.objects.size(), truth.objects.size());  // the host is not an object
  for (std::size_t i = 0; i < truth.objects.size(); ++i) {
    const auto& a = scene.map.objects[i];
    const auto& b = truth.objects[i];
    EXPECT_EQ(ids.to_osi(a.id), static_cast<std::uint64_t>(b.id));
    EXPECT_EQ(a.cls, b.cls);
    EXPECT_LT((a.position - b.position).norm(), 1e-9);
    EXPECT_LT((a.velocity - b.velocity).norm(), 1e-9);
    EXPECT_LT((a.size - b.size).norm(), 1e-9);
    EXPECT_NEAR(a.heading, b.heading, 1e-9);
  }
  ASSERT_EQ(scene.map.lanes.size(), truth.lanes.size());
  for (std::size_t i = 0; i < truth.lanes.size(); ++i) {
    EXPECT_EQ(scene.map.lanes[i].type, truth.lanes[i].type);
    EXPECT_EQ(scene.map.lanes[i].points.size(), truth.lanes[i].points.size());
  }
}

TEST(OsiSensorView, MountIsRaisedByTheRearAxleHeightAboveTheRoad) {
  using namespace lidarsim;
  // Host box centre 0.75 m above the road (1.5 m tall), rear axle 0.45 m below the centre: the
  // axle is 0.3 m above the road, so a mount 1.43 m above the axle is 1.73 m above the road.
  osi3::SensorView v;
  v.mutable_host_vehicle_id()->set_value(99);
  auto* mp = v.mutable_mounting_position()->mutable_position();
  mp->set_x(1.0);
  mp->set_z(1.43);
  auto* host = v.mutable_global_ground_truth()->add_moving_object();
  host->mutable_id()->set_value(99);
  host->set_type(osi3::MovingObject::TYPE_VEHICLE);
  auto* b = host->mutable_base();
  b->mutable_position()->set_x(11.4);
  b->mutable_position()->set_y(-2);
  b->mutable_position()->set_z(5.75);  // a road 5 m above the map origin
  b->mutable_orientation()->set_yaw(0.5);
  b->mutable_dimension()->set_length(4.5);
  b->mutable_dimension()->set_width(1.8);
  b->mutable_dimension()->set_height(1.5);
  auto* r = host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear();
  r->set_x(-1.4);
  r->set_z(-0.45);
  osi::IdMap ids;
  osi::SceneFrame scene;
  osi::scene_from_sensor_view(v, 0, "hand", ids, scene);
  EXPECT_NEAR(scene.mount.translation.x(), 1.0, 1e-12);
  EXPECT_NEAR(scene.mount.translation.z(), 1.73, 1e-12);
  const Eigen::Vector3d rear_axle_ground(11.4 - 1.4 * std::cos(0.5), -2 - 1.4 * std::sin(0.5), 5.0);
  EXPECT_LT((scene.map.ego_in_map.translation - rear_axle_ground).norm(), 1e-12);
  EXPECT_TRUE(scene.map.objects.empty());
}

TEST(OsiSensorView, HostIdNotAmongObjectsIsAnErrorNamingTheField) {
  osi3::SensorView v;
  v.mutable_host_vehicle_id()->set_value(5);
  v.mutable_mounting_position();
  v.mutable_global_ground_truth()->add_moving_object()->mutable_id()->set_value(6);
  lidarsim::osi::IdMap ids;
  lidarsim::osi::SceneFrame scene;
  try {
    lidarsim::osi::scene_from_sensor_view(v, 2, "x.osi", ids, scene);
    FAIL();
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("x.osi: message 2: host_vehicle_id: 5 is not among"), std::string::npos)
        << e.what();
  }
}

TEST(OsiSensorView, VehicleTypesMapToOurClassesAndBack) {
  using lidarsim::sensor::ObjectClass;
  namespace msg = lidarsim::osi::msg;
  msg::MovingObject o;
  o.type = msg::kTypeVehicle;
  const std::pair<msg::VehicleType, ObjectClass> cases[] = {{msg::kCompactCar, ObjectClass::Car},
                                                            {msg::kDeliveryVan, ObjectClass::Van},
                                                            {msg::kSemitrailer, ObjectClass::Truck},
                                                            {msg::kBus, ObjectClass::Bus},
                                                            {msg::kMotorbike, ObjectClass::Motorcycle},
                                                            {msg::kBicycle, ObjectClass::Cyclist}};
  for (const auto& [type, cls] : cases) {
    o.vehicle_type = type;
    EXPECT_EQ(lidarsim::osi::class_from_osi(o), cls) << type;
    o.vehicle_type = lidarsim::osi::osi_vehicle_type(cls);
    EXPECT_EQ(lidarsim::osi::class_from_osi(o), cls) << "back from " << type;
  }
  o.type = msg::kTypePedestrian;
  EXPECT_EQ(lidarsim::osi::class_from_osi(o), ObjectClass::Pedestrian);
  EXPECT_EQ(static_cast<int>(lidarsim::osi::osi_type(ObjectClass::Pedestrian)),
            static_cast<int>(osi3::MovingObject::TYPE_PEDESTRIAN));
}

// Lane boundaries are split to 0.5 m as scenario lanes are: points 1e300 m apart made an
// infinite point count (UBSan, found by the osi_trace fuzz target), 1e7 m apart 2e7 points.
TEST(OsiSensorView, LaneBoundaryLongerThanAScenarioLaneIsAnErrorNamingThePoint) {
  for (const double far : {1e300, 1e7}) {
    osi3::SensorView v;
    v.mutable_host_vehicle_id()->set_value(5);
    v.mutable_mounting_position();
    v.mutable_global_ground_truth()->add_moving_object()->mutable_id()->set_value(5);
    auto* lane = v.mutable_global_ground_truth()->add_lane_boundary();
    lane->mutable_id()->set_value(9);
    lane->mutable_classification()->set_type(osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
    lane->add_boundary_line()->mutable_position()->set_x(-far);
    lane->add_boundary_line()->mutable_position()->set_x(far);
    lidarsim::osi::IdMap ids;
    lidarsim::osi::SceneFrame scene;
    try {
      lidarsim::osi::scene_from_sensor_view(v, 0, "x.osi", ids, scene);
      FAIL() << far;
    } catch (const lidarsim::Error& e) {
      EXPECT_NE(std::string(e.what()).find("x.osi: message 0: global_ground_truth.lane_boundary[0].boundary_line[1]: the lane is"),
                std::string::npos)
          << e.what();
    }
  }
}

// Scenery goes out as stationary objects and comes back as the same boxes, class and material
// where OSI has a type for them; a tree goes out as one box and comes back as a tree of the
// reader's proportions standing on the same foot, as tall and as wide.
TEST(OsiSensorView, ScenarioSceneryThroughOsiComesBackBoxForBoxAndTreeForTree) {
  using namespace lidarsim;
  namespace c = pgm::cls;
  osi3::SensorView v;
  osi::sensor_view_from_scenario(demo(), 1.0, v);
  osi::IdMap ids;
  osi::SceneFrame scene;
  osi::scene_from_sensor_view(v, 0, "demo", ids, scene);
  sensor::Frame truth;
  sensor::sample_frame(demo(), 1.0, truth);
  const auto& in = truth.scenery;
  const auto& out = scene.map.scenery;
  ASSERT_GT(in.size(), 100u);
  ASSERT_EQ(out.size(), in.size());  // a tree is five boxes either way
  int trees = 0, exact = 0;
  for (std::size_t i = 0; i < in.size(); ++i) {
    SCOPED_TRACE("box " + std::to_string(i) + " of class " + pgm::class_name(in[i].class_id));
    if (in[i].class_id == c::trunk) {  // the trunk, then the crown's four boxes
      ++trees;
      const double foot = in[i].position.z() - 0.5 * in[i].size.z();
      EXPECT_EQ(out[i].class_id, c::trunk);
      EXPECT_NEAR(out[i].position.z() - 0.5 * out[i].size.z(), foot, 1e-9);
      EXPECT_NEAR((out[i].position - in[i].position).head<2>().norm(), 0, 1e-9);
      const auto top = [](const sensor::SceneryBox& b) { return b.position.z() + 0.5 * b.size.z(); };
      EXPECT_NEAR(top(out[i + 4]), top(in[i + 4]), 1e-9);                    // as tall
      EXPECT_NEAR(out[i + 2].size.x(), in[i + 2].size.x(), 1e-9);            // as wide
      for (int k = 1; k <= 4; ++k) EXPECT_EQ(out[i + k].class_id, c::vegetation);
      i += 4;
      continue;
    }
    EXPECT_LT((out[i].position - in[i].position).norm(), 1e-9);
    EXPECT_LT((out[i].size - in[i].size).norm(), 1e-9);
    EXPECT_NEAR(std::remainder(out[i].heading - in[i].heading, 2 * std::numbers::pi), 0, 1e-12);
    if (in[i].class_id == c::traffic_sign) {  // OSI has no sign among stationary objects
      EXPECT_EQ(out[i].class_id, c::pole);
      EXPECT_EQ(out[i].material_id, pgm::material::retroreflective_sign);
      continue;
    }
    EXPECT_EQ(out[i].class_id, in[i].class_id);
    EXPECT_EQ(out[i].material_id, in[i].material_id);
    ++exact;
  }
  EXPECT_EQ(trees, 48);
  EXPECT_GT(exact, 50);
}
