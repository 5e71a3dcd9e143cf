// OSI stationary objects as static scenery: global_ground_truth.stationary_object becomes scenery
// boxes (class and material from the OSI classification) that occlude and return points like a
// scenario's "scenery", and bad ones are one error naming the field.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <string>

#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "pgm/materials.h"
#include "sensor/scenery.h"

namespace {

using Classification = osi3::StationaryObject::Classification;

// The host (id 99) at the origin, its rear axle 0.3 m above the road, the sensor 1.73 m up.
osi3::SensorView stationary_view_with_host(double t) {
  osi3::SensorView v;
  v.mutable_timestamp()->set_seconds(0);
  v.mutable_timestamp()->set_nanos(static_cast<std::uint32_t>(std::lround(t * 1e9)));
  v.mutable_sensor_id()->set_value(7);
  v.mutable_host_vehicle_id()->set_value(99);
  v.mutable_mounting_position()->mutable_position()->set_x(1.0);
  v.mutable_mounting_position()->mutable_position()->set_z(1.43);
  auto* host = v.mutable_global_ground_truth()->add_moving_object();
  host->mutable_id()->set_value(99);
  host->set_type(osi3::MovingObject::TYPE_VEHICLE);
  auto* b = host->mutable_base();
  b->mutable_position()->set_x(1.4);
  b->mutable_position()->set_z(0.75);
  b->mutable_dimension()->set_length(4.5);
  b->mutable_dimension()->set_width(1.8);
  b->mutable_dimension()->set_height(1.5);
  auto* rear = host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear();
  rear->set_x(-1.4);
  rear->set_z(-0.45);
  return v;
}

osi3::StationaryObject& stationary_add(osi3::SensorView& v, std::uint64_t id, Classification::Type type, double x,
                                       double y, double l, double w, double h, double yaw = 0) {
  auto* o = v.mutable_global_ground_truth()->add_stationary_object();
  o->mutable_id()->set_value(id);
  o->mutable_classification()->set_type(type);
  auto* b = o->mutable_base();
  b->mutable_position()->set_x(x);
  b->mutable_position()->set_y(y);
  b->mutable_position()->set_z(0.5 * h);  // standing on the road
  b->mutable_dimension()->set_length(l);
  b->mutable_dimension()->set_width(w);
  b->mutable_dimension()->set_height(h);
  b->mutable_orientation()->set_yaw(yaw);
  return *o;
}

lidarsim::osi::SceneFrame stationary_scene(const osi3::SensorView& v) {
  lidarsim::osi::IdMap ids;
  lidarsim::osi::SceneFrame scene;
  lidarsim::osi::scene_from_sensor_view(v, 0, "hand", ids, scene);
  return scene;
}

}  // namespace

TEST(OsiStationaryObjects, BecomeSceneryBoxesWithTheirClassMaterialAndPose) {
  using namespace lidarsim;
  osi3::SensorView v = stationary_view_with_host(0);
  stationary_add(v, 1, Classification::TYPE_BUILDING, 20, 10, 12, 8, 9, 0.3);
  stationary_add(v, 2, Classification::TYPE_CURBSTONE, 5, -3, 30, 0.3, 0.12);
  stationary_add(v, 3, Classification::TYPE_POLE, 8, 4, 0.2, 0.2, 6)
      .mutable_classification()
      ->set_material(Classification::MATERIAL_METAL);
  stationary_add(v, 4, Classification::TYPE_REFLECTIVE_STRUCTURE, 9, -4, 0.1, 0.1, 1);
  stationary_add(v, 5, Classification::TYPE_WALL, 30, 0, 0.3, 10, 2)
      .mutable_classification()
      ->set_material(Classification::MATERIAL_GLAS);
  stationary_add(v, 6, Classification::TYPE_TREE, 12, 6, 4, 4, 8);
  const osi::SceneFrame scene = stationary_scene(v);

  const auto& s = scene.map.scenery;
  ASSERT_EQ(s.size(), 5u + 5u);  // five boxes, and a tree of a trunk and four crown boxes
  EXPECT_EQ(s[0].class_id, pgm::cls::building);
  EXPECT_EQ(s[0].material_id, pgm::default_material(pgm::cls::building));
  EXPECT_LT((s[0].position - Eigen::Vector3d(20, 10, 4.5)).norm(), 1e-12);  // the box's centre, as in OSI
  EXPECT_LT((s[0].size - Eigen::Vector3d(12, 8, 9)).norm(), 1e-12);
  EXPECT_DOUBLE_EQ(s[0].heading, 0.3);
  EXPECT_EQ(s[1].class_id, pgm::cls::sidewalk);
  EXPECT_EQ(s[2].class_id, pgm::cls::pole);
  EXPECT_EQ(s[2].material_id, pgm::material::metal);
  EXPECT_EQ(s[3].class_id, pgm::cls::pole);
  EXPECT_EQ(s[3].material_id, pgm::material::retroreflective_sign);
  EXPECT_EQ(s[4].class_id, pgm::cls::other_structure);
  EXPECT_EQ(s[4].material_id, pgm::material::glass);
  EXPECT_EQ(s[5].class_id, pgm::cls::trunk);
  double top = 0;
  for (std::size_t k = 5; k < s.size(); ++k) {
    if (k > 5) {
      EXPECT_EQ(s[k].class_id, pgm::cls::vegetation);
    }
    EXPECT_EQ(s[k].element, 5);  // the stationary object's index
    EXPECT_NEAR(s[k].position.x(), 12, 1e-12);
    top = std::max(top, s[k].position.z() + 0.5 * s[k].size.z());
  }
  EXPECT_NEAR(top, 8, 1e-9);  // the tree stays inside its box
  EXPECT_NEAR(s[5].position.z() - 0.5 * s[5].size.z(), 0, 1e-9);
}

// A patch of soil has no OSI type: "other" or "unknown" of mud is terrain (osi/scenario_trace.cpp
// writes terrain so); of any other material, or a pylon of mud, it stays other_object.
TEST(OsiStationaryObjects, OtherOrUnknownOfMudIsTerrain) {
  using namespace lidarsim;
  osi3::SensorView v = stationary_view_with_host(0);
  stationary_add(v, 1, Classification::TYPE_OTHER, 20, 10, 5, 5, 0.1).mutable_classification()->set_material(
      Classification::MATERIAL_MUD);
  stationary_add(v, 2, Classification::TYPE_UNKNOWN, 20, -10, 5, 5, 0.1).mutable_classification()->set_material(
      Classification::MATERIAL_MUD);
  stationary_add(v, 3, Classification::TYPE_OTHER, 30, 0, 5, 5, 0.1).mutable_classification()->set_material(
      Classification::MATERIAL_WOOD);
  stationary_add(v, 4, Classification::TYPE_PYLON, 10, 0, 0.3, 0.3, 0.8).mutable_classification()->set_material(
      Classification::MATERIAL_MUD);
  const auto& s = stationary_scene(v).map.scenery;
  ASSERT_EQ(s.size(), 4u);
  EXPECT_EQ(s[0].class_id, pgm::cls::terrain);
  EXPECT_EQ(s[1].class_id, pgm::cls::terrain);
  EXPECT_EQ(s[0].material_id, pgm::material::terrain);
  EXPECT_EQ(s[2].class_id, pgm::cls::other_object);
  EXPECT_EQ(s[3].class_id, pgm::cls::other_object);
}

TEST(OsiStationaryObjects, BadOnesAreOneErrorNamingTheField) {
  using namespace lidarsim;
  const auto message = [](const osi3::SensorView& v) {
    try {
      stationary_scene(v);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  {
    osi3::SensorView v = stationary_view_with_host(0);
    stationary_add(v, 1, Classification::TYPE_BUILDING, 20, 10, 12, 8, 9);
    stationary_add(v, 2, Classification::TYPE_BUILDING, 20, 10, 12, 0, 9);
    EXPECT_EQ(message(v),
              "hand: message 0: global_ground_truth.stationary_object[1].base.dimension: must be positive (length, "
              "width and height)");
  }
  {
    osi3::SensorView v = stationary_view_with_host(0);
    stationary_add(v, 1, Classification::TYPE_POLE, 20, 10, 1, 1, 9).mutable_base()->clear_position();
    EXPECT_EQ(message(v), "hand: message 0: global_ground_truth.stationary_object[0].base.position: missing");
  }
  {
    osi3::SensorView v = stationary_view_with_host(0);
    stationary_add(v, 1, Classification::TYPE_POLE, 20, NAN, 1, 1, 9);
    EXPECT_EQ(message(v), "hand: message 0: global_ground_truth.stationary_object[0].base: not finite");
  }
  {  // more trees than the model takes boxes (each is a trunk and four crown boxes)
    osi3::SensorView v = stationary_view_with_host(0);
    for (int k = 0; k < lidarsim::sensor::kMaxSceneryBoxes / 5 + 1; ++k)
      stationary_add(v, 10 + k, Classification::TYPE_TREE, k, 30, 4, 4, 8);
    EXPECT_EQ(message(v), "hand: message 0: global_ground_truth.stationary_object: 50005 scenery boxes, at most 50000");
  }
}

// A wall 8 m ahead of the sensor hides a van 15 m ahead: no track, no return on the van, and the
// returns straight ahead come from the wall's face, 7 m from the sensor (1 m ahead of the axle).
TEST(OsiStationaryObjects, AWallOccludesAVanAndReturnsPoints) {
  using namespace lidarsim;
  const std::string src = LIDARSIM_SOURCE_DIR;
  infer::SimOptions options;
  options.kpi.noise = options.kpi.misses = options.kpi.false_positives = options.kpi.flips = false;
  auto runner = infer::OsiRunner::from_files(src + "/data/scenarios/demo_urban.json",
                                             src + "/data/models/kpi_pointrcnn.json",
                                             src + "/data/models/intensity_unet.h5", options);
  osi3::SensorData out;
  for (int k = 0; k < 3; ++k) {
    osi3::SensorView v = stationary_view_with_host(0.1 * k);
    auto* van = v.mutable_global_ground_truth()->add_moving_object();
    van->mutable_id()->set_value(11);
    van->set_type(osi3::MovingObject::TYPE_VEHICLE);
    auto* b = van->mutable_base();
    b->mutable_position()->set_x(15);
    b->mutable_position()->set_z(1.1);
    b->mutable_dimension()->set_length(5);
    b->mutable_dimension()->set_width(2);
    b->mutable_dimension()->set_height(2.2);
    stationary_add(v, 500, Classification::TYPE_WALL, 8.5, 0, 1, 12, 4);
    runner.step(v, k, "hand", out);
  }
  EXPECT_EQ(out.moving_object_size(), 0);
  std::map<std::uint64_t, int> hits;
  int on_the_wall = 0;
  for (const auto& d : out.feature_data().lidar_sensor(0).detection()) {
    ++hits[d.object_id().value()];
    if (std::abs(d.position().azimuth()) < 0.05 && std::abs(d.position().elevation()) < 0.05) {
      EXPECT_NEAR(d.position().distance(), 7.0, 0.05);  // the face at x = 8 m, the sensor at x = 1 m
      ++on_the_wall;
    }
  }
  EXPECT_EQ(hits.count(11), 0u);
  EXPECT_GT(on_the_wall, 10);
}
