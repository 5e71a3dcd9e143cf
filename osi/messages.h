#pragma once
// The osi3.SensorView subset we read, as plain structs (no Protocol Buffers): what
// osi/sensor_view_decoder.h decodes from the wire and osi/sensor_view.h turns into our scene.
// Field names and numbers are those of osi/proto/osi3_subset.proto; fields we never read are
// not kept (the decoder still checks their bytes as libprotobuf would).
//
// proto2 presence: `has` holds one bit per optional field that was on the wire (bit k - 1 for
// field number k) where the scene or the echo needs it. The messages the SensorData echoes
// (Timestamp, Identifier, MountingPosition with its Vector3d and Orientation3d) also keep the
// fields our subset does not know, in `unknown`, as libprotobuf re-serializes them (in arrival
// order, each tag and varint in its shortest form), so that our echo is libprotobuf's byte for byte.
#include <cstdint>
#include <string>
#include <vector>

namespace lidarsim::osi::msg {

constexpr std::uint32_t bit(int field) { return 1u << (field - 1); }

struct Vector3d {  // x (1), y (2), z (3)
  double x = 0, y = 0, z = 0;
  std::uint32_t has = 0;
  std::string unknown;
};

struct Orientation3d {  // roll (1), pitch (2), yaw (3)
  double roll = 0, pitch = 0, yaw = 0;
  std::uint32_t has = 0;
  std::string unknown;
};

struct Dimension3d {  // length (1), width (2), height (3)
  double length = 0, width = 0, height = 0;
};

struct Timestamp {  // seconds (1, int64), nanos (2, uint32)
  std::int64_t seconds = 0;
  std::uint32_t nanos = 0;
  std::uint32_t has = 0;
  std::string unknown;
};

struct Identifier {  // value (1, uint64)
  std::uint64_t value = 0;
  std::uint32_t has = 0;
  std::string unknown;
};

struct MountingPosition {  // position (1), orientation (2)
  Vector3d position;
  Orientation3d orientation;
  std::uint32_t has = 0;
  std::string unknown;
};

struct BaseMoving {  // dimension (1), position (2), orientation (3), velocity (4), acceleration (5)
  Dimension3d dimension;
  Vector3d position;
  Orientation3d orientation;
  Vector3d velocity, acceleration;
  std::uint32_t has = 0;
};

// Enum values of the subset (closed proto2 enums: a value outside them leaves the field unset).
enum MovingObjectType : int { kTypeUnknown = 0, kTypeOther, kTypeVehicle, kTypePedestrian, kTypeAnimal };
inline constexpr int kMovingObjectTypeCount = 5;
enum VehicleType : int {
  kVehicleUnknown = 0, kVehicleOther, kSmallCar, kCompactCar, kMediumCar, kLuxuryCar, kDeliveryVan, kHeavyTruck,
  kSemitrailer, kTrailer, kMotorbike, kBicycle, kBus, kTram, kTrain, kWheelchair
};
inline constexpr int kVehicleTypeCount = 16;
enum LaneBoundaryType : int {
  kLaneUnknown = 0, kLaneOther, kNoLine, kSolidLine, kDashedLine, kBottsDots, kRoadEdge, kSnowEdge, kGrassEdge,
  kGravelEdge, kSoilEdge, kGuardRail, kCurb, kStructure
};
inline constexpr int kLaneBoundaryTypeCount = 14;
// The SensorData's enums we write (osi/sensor_data_encoder.cpp).
inline constexpr int kDataQualifierAvailable = 2;  // DetectedEntityHeader and SensorDetectionHeader
inline constexpr int kMeasurementStateMeasured = 2, kMeasurementStatePredicted = 3;
inline constexpr int kReferencePointCenter = 2;

struct BaseStationary {  // dimension (1), position (2), orientation (3)
  Dimension3d dimension;
  Vector3d position;
  Orientation3d orientation;
  std::uint32_t has = 0;
};

// StationaryObject.Classification's enums.
enum StationaryType : int {
  kStationaryUnknown = 0, kStationaryOther, kBridge, kBuilding, kPole, kPylon, kDelineator, kTree, kBarrier,
  kVegetation, kCurbstone, kWall, kVerticalStructure, kRectangularStructure, kOverheadStructure,
  kReflectiveStructure, kConstructionSiteElement, kSpeedBump, kEmittingStructure
};
inline constexpr int kStationaryTypeCount = 19;
enum StationaryMaterial : int {
  kMaterialUnknown = 0, kMaterialOther, kWood, kPlastic, kConcrete, kMetal, kStone, kGlas, kMud
};
inline constexpr int kStationaryMaterialCount = 9;

struct StationaryObject {  // id (1), base (2), classification (3: type (1), material (2))
  Identifier id;
  BaseStationary base;
  StationaryType type = kStationaryUnknown;
  StationaryMaterial material = kMaterialUnknown;
  std::uint32_t has = 0;
};

struct MovingObject {  // id (1), base (2), type (3), vehicle_attributes (5), vehicle_classification (6)
  Identifier id;
  BaseMoving base;
  MovingObjectType type = kTypeUnknown;
  VehicleType vehicle_type = kVehicleUnknown;  // vehicle_classification.type
  Vector3d bbcenter_to_rear;                   // vehicle_attributes.bbcenter_to_rear
  std::uint32_t has = 0;
};

struct LaneBoundary {  // id (1), boundary_line (2: BoundaryPoint.position), classification (3)
  Identifier id;
  std::vector<Vector3d> boundary_line;  // each BoundaryPoint's position
  LaneBoundaryType type = kLaneUnknown;  // classification.type
  std::uint32_t has = 0;
};

// timestamp (2), host_vehicle_id (3), stationary_object (4), moving_object (5), lane_boundary (9)
struct GroundTruth {
  Timestamp timestamp;
  Identifier host_vehicle_id;
  std::vector<StationaryObject> stationary_object;
  std::vector<MovingObject> moving_object;
  std::vector<LaneBoundary> lane_boundary;
  std::uint32_t has = 0;
};

struct LidarSensorViewConfiguration {  // sensor_id (1), mounting_position (2)
  Identifier sensor_id;
  MountingPosition mounting_position;
  std::uint32_t has = 0;
};

// timestamp (2), sensor_id (3), mounting_position (4), global_ground_truth (7), host_vehicle_id
// (8), lidar_sensor_view (1002: LidarSensorView.view_configuration (1)).
struct SensorView {
  Timestamp timestamp;
  Identifier sensor_id;
  MountingPosition mounting_position;
  GroundTruth global_ground_truth;
  Identifier host_vehicle_id;
  std::vector<LidarSensorViewConfiguration> lidar_sensor_view;  // each entry's view_configuration
  std::uint64_t has = 0;  // bit(k) for k < 32; lidar_sensor_view has no bit (it is repeated)
};

}  // namespace lidarsim::osi::msg
