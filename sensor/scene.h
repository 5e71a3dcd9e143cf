#pragma once
// Scene types shared by every stage of the phenomenological model. ISO 8855 axes (x forward,
// y left, z up), SI units, radians inside; degrees only at the edges (files, CLI).
#include <Eigen/Core>
#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace lidarsim::sensor {

enum class ObjectClass { Car, Truck, Van, Bus, Pedestrian, Cyclist, Motorcycle, Misc };
// The number of ObjectClass values (tables indexed by class have this many entries).
inline constexpr int kNumObjectClasses = 8;
static_assert(static_cast<int>(ObjectClass::Misc) + 1 == kNumObjectClasses, "kNumObjectClasses: one per ObjectClass");
std::string to_string(ObjectClass c);
ObjectClass object_class_from_string(const std::string& name);  // throws lidarsim::Error

struct Pose {  // rigid transform: p_parent = rotation * p_child + translation
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

// A ground-truth or reported object: a box whose centre is the box's geometric centre.
struct Object {
  int id = -1;                 // ground-truth id (or track id after tracking)
  ObjectClass cls = ObjectClass::Car;
  std::string material = "car_paint";
  Eigen::Vector3d position = Eigen::Vector3d::Zero();      // box centre, in the frame of the list
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();
  Eigen::Vector3d acceleration = Eigen::Vector3d::Zero();
  Eigen::Vector3d size = Eigen::Vector3d::Ones();          // length (x), width (y), height (z)
  double heading = 0;          // yaw about z, radians
  double visible_fraction = 1; // share of the box the sensor sees: set by occlusion, times (1 - truncation)
  double truncation = 0;       // share of the box outside the field of view, 0..1 (KITTI "truncated"); set by
                               // the FoV stage (sensor/fov.h) or read from labels
  double score = 1;            // detection confidence, for reported objects
};

enum class LaneType { Solid, Dashed, RoadEdge };

struct LanePolyline {
  int id = -1;
  LaneType type = LaneType::Solid;
  std::vector<Eigen::Vector3d> points;  // in the frame of the frame they belong to
};

// A visible lane marking as y(x) = c0 + c1 x + c2 x^2 + c3 x^3 in the sensor frame.
struct LanePolynomial {
  int id = -1;
  LaneType type = LaneType::Solid;
  double c0 = 0, c1 = 0, c2 = 0, c3 = 0;
  double x_min = 0, x_max = 0;  // valid range
};

// A static part of the scene (building, wall, fence, hedge, tree trunk or crown, pole, sign
// plate, sidewalk slab, terrain patch) as a yaw-only box with its PGM labels. Scenery is not an
// object: it blocks beams (occlusion of objects and lanes, returns in the point cloud) but is
// never tracked or reported. Parked cars are objects (a detector must find them), not scenery.
struct SceneryBox {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // box centre, in the frame of the list
  Eigen::Vector3d size = Eigen::Vector3d::Ones();      // length (x), width (y), height (z)
  double heading = 0;                                  // yaw about z, radians
  int class_id = 0;                                    // pgm::cls id
  int material_id = 0;                                 // pgm::material id
  int element = -1;                                    // index of the scenario's scenery element
};

struct Frame {
  double time = 0;             // seconds
  Pose ego_in_map;             // ego pose at this time
  std::vector<Object> objects;
  std::vector<LanePolyline> lanes;
  std::vector<SceneryBox> scenery;  // static scenery (scenario "scenery", OSI stationary objects)
};

}  // namespace lidarsim::sensor
