// The osi3 subset against the official wire format: bytes we write are the bytes the official
// field numbers and types give (hand-encoded here from the official .proto files), messages
// round-trip, and fields we do not know survive a parse.
#include <gtest/gtest.h>

#include <cstring>
#include <string>

#include "osi/osi3_subset.pb.h"
#include "osi/scenario_trace.h"
#include "sensor/scenario.h"

namespace {

std::string bytes(std::initializer_list<unsigned> b) {
  std::string s;
  for (unsigned v : b) s += static_cast<char>(v);
  return s;
}

std::string le_double(double d) {
  char b[8];
  std::memcpy(b, &d, 8);  // x86-64 is little-endian like the wire format
  return std::string(b, 8);
}

}  // namespace

TEST(OsiSchema, SensorViewIdsEncodeWithTheOfficialFieldNumbers) {
  osi3::SensorView v;
  v.mutable_sensor_id()->set_value(5);        // SensorView.sensor_id = 3, Identifier.value = 1 (uint64)
  v.mutable_host_vehicle_id()->set_value(7);  // SensorView.host_vehicle_id = 8
  // field 3, wire type 2: 0x1a; field 8, wire type 2: 0x42; Identifier.value varint: 0x08
  EXPECT_EQ(v.SerializeAsString(), bytes({0x1a, 0x02, 0x08, 0x05, 0x42, 0x02, 0x08, 0x07}));
}

TEST(OsiSchema, HandEncodedGroundTruthMovingObjectDecodes) {
  // SensorView.global_ground_truth (7) { GroundTruth.moving_object (5) { MovingObject.id (1) {value 42},
  //   base (2) { BaseMoving.position (2) { Vector3d.x (1, double) = 12.5 } }, type (3) = TYPE_PEDESTRIAN (3) } }
  const std::string x = bytes({0x09}) + le_double(12.5);                   // Vector3d.x: field 1, fixed64
  const std::string position = bytes({0x12, static_cast<unsigned>(x.size())}) + x;  // BaseMoving.position = 2
  const std::string object = bytes({0x0a, 0x02, 0x08, 42}) +                // id
                             bytes({0x12, static_cast<unsigned>(position.size())}) + position +  // base
                             bytes({0x18, 0x03});                          // type = 3, varint
  const std::string gt = bytes({0x2a, static_cast<unsigned>(object.size())}) + object;  // moving_object = 5
  const std::string view = bytes({0x3a, static_cast<unsigned>(gt.size())}) + gt;        // global_ground_truth = 7
  osi3::SensorView v;
  ASSERT_TRUE(v.ParseFromString(view));
  ASSERT_EQ(v.global_ground_truth().moving_object_size(), 1);
  const auto& o = v.global_ground_truth().moving_object(0);
  EXPECT_EQ(o.id().value(), 42u);
  EXPECT_EQ(o.type(), osi3::MovingObject::TYPE_PEDESTRIAN);
  EXPECT_DOUBLE_EQ(o.base().position().x(), 12.5);
}

TEST(OsiSchema, LidarDetectionIntensityEncodesUnderFeatureData26) {
  osi3::SensorData d;
  d.mutable_feature_data()->add_lidar_sensor()->add_detection()->set_intensity(50.0);
  // SensorData.feature_data = 26 (tag 26<<3|2 = 210 = varint d2 01), FeatureData.lidar_sensor = 3 (0x1a),
  // LidarDetectionData.detection = 2 (0x12), LidarDetection.intensity = 7, double (7<<3|1 = 0x39).
  const std::string det = bytes({0x39}) + le_double(50.0);
  const std::string lidar = bytes({0x12, static_cast<unsigned>(det.size())}) + det;
  const std::string feature = bytes({0x1a, static_cast<unsigned>(lidar.size())}) + lidar;
  EXPECT_EQ(d.SerializeAsString(), bytes({0xd2, 0x01, static_cast<unsigned>(feature.size())}) + feature);
}

TEST(OsiSchema, DetectedMovingObjectHeaderAndCandidateUseOfficialNumbers) {
  osi3::SensorData d;
  auto* m = d.add_moving_object();                      // SensorData.moving_object = 13 -> tag 0x6a
  m->mutable_header()->mutable_tracking_id()->set_value(3);  // header = 1, tracking_id = 1
  m->add_candidate()->set_type(osi3::MovingObject::TYPE_VEHICLE);  // candidate = 8 (0x42), type = 2 (0x10)
  const std::string header = bytes({0x0a, 0x02, 0x08, 0x03});
  const std::string candidate = bytes({0x10, 0x02});
  const std::string object = bytes({0x0a, static_cast<unsigned>(header.size())}) + header +
                             bytes({0x42, static_cast<unsigned>(candidate.size())}) + candidate;
  EXPECT_EQ(d.SerializeAsString(), bytes({0x6a, static_cast<unsigned>(object.size())}) + object);
}

TEST(OsiSchema, UnknownFieldsOfTheFullSchemaParseAndSurviveReserialization) {
  osi3::SensorView v;
  v.mutable_sensor_id()->set_value(1);
  // SensorView.lidar_sensor_view = 1002 (tag 1002<<3|2 = 8018 = varint d2 3e) with an empty
  // message, and GroundTruth.country_code = 13 inside global_ground_truth: neither is in our subset.
  const std::string extra = bytes({0xd2, 0x3e, 0x00}) + bytes({0x3a, 0x02, 0x68, 0x11});
  const std::string wire = v.SerializeAsString() + extra;
  osi3::SensorView parsed;
  ASSERT_TRUE(parsed.ParseFromString(wire));
  EXPECT_EQ(parsed.sensor_id().value(), 1u);
  EXPECT_TRUE(parsed.has_global_ground_truth());
  EXPECT_EQ(parsed.SerializeAsString().size(), wire.size());
}

TEST(OsiSchema, ScenarioSensorViewRoundTripsThroughTheWire) {
  const auto scenario = lidarsim::sensor::read_scenario(std::string(LIDARSIM_SOURCE_DIR) + "/data/scenarios/demo_urban.json");
  osi3::SensorView v;
  lidarsim::osi::sensor_view_from_scenario(scenario, 1.0, v);
  osi3::SensorView back;
  ASSERT_TRUE(back.ParseFromString(v.SerializeAsString()));
  EXPECT_EQ(back.SerializeAsString(), v.SerializeAsString());
  EXPECT_EQ(back.DebugString(), v.DebugString());
  EXPECT_GT(back.global_ground_truth().moving_object_size(), 1);
  EXPECT_GT(back.global_ground_truth().lane_boundary_size(), 0);
}
