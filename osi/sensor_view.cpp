#include "osi/sensor_view.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "pgm/materials.h"
#include "sensor/frames.h"
#include "sensor/scenario.h"
#include "sensor/scenery.h"

namespace lidarsim::osi {

int IdMap::to_model(std::uint64_t osi_id) {
  const auto [it, inserted] = to_model_.try_emplace(osi_id, static_cast<int>(to_osi_.size()));
  if (inserted) to_osi_.push_back(osi_id);
  return it->second;
}

double seconds(const msg::Timestamp& t) { return static_cast<double>(t.seconds) + t.nanos * 1e-9; }

sensor::Pose pose_from_osi(const msg::Vector3d& p, const msg::Orientation3d& o) {
  return sensor::make_pose(Eigen::Vector3d(p.x, p.y, p.z), o.roll, o.pitch, o.yaw);
}

sensor::ObjectClass class_from_osi(const msg::MovingObject& o) {
  switch (o.type) {
    case msg::kTypePedestrian: return sensor::ObjectClass::Pedestrian;
    case msg::kTypeVehicle:
      switch (o.vehicle_type) {
        case msg::kDeliveryVan: return sensor::ObjectClass::Van;
        case msg::kHeavyTruck:
        case msg::kSemitrailer:
        case msg::kTrailer: return sensor::ObjectClass::Truck;
        case msg::kBus:
        case msg::kTram:
        case msg::kTrain: return sensor::ObjectClass::Bus;
        case msg::kMotorbike: return sensor::ObjectClass::Motorcycle;
        case msg::kBicycle: return sensor::ObjectClass::Cyclist;
        case msg::kWheelchair: return sensor::ObjectClass::Misc;
        default: return sensor::ObjectClass::Car;
      }
    default: return sensor::ObjectClass::Misc;
  }
}

msg::MovingObjectType osi_type(sensor::ObjectClass c) {
  switch (c) {
    case sensor::ObjectClass::Pedestrian: return msg::kTypePedestrian;
    case sensor::ObjectClass::Misc: return msg::kTypeOther;
    default: return msg::kTypeVehicle;
  }
}

msg::VehicleType osi_vehicle_type(sensor::ObjectClass c) {
  switch (c) {
    case sensor::ObjectClass::Car: return msg::kMediumCar;
    case sensor::ObjectClass::Van: return msg::kDeliveryVan;
    case sensor::ObjectClass::Truck: return msg::kHeavyTruck;
    case sensor::ObjectClass::Bus: return msg::kBus;
    case sensor::ObjectClass::Motorcycle: return msg::kMotorbike;
    case sensor::ObjectClass::Cyclist: return msg::kBicycle;
    default: return msg::kVehicleOther;
  }
}

namespace {

// Longest lane accepted, as for scenario lanes (sensor/scenario.cpp).
constexpr double kMaxLaneLength = 100000;  // m

sensor::LaneType lane_type(const msg::LaneBoundary& b, bool& drawn) {
  drawn = true;
  switch (b.type) {
    case msg::kNoLine: drawn = false; return sensor::LaneType::Solid;
    case msg::kDashedLine:
    case msg::kBottsDots: return sensor::LaneType::Dashed;
    case msg::kRoadEdge:
    case msg::kSnowEdge:
    case msg::kGrassEdge:
    case msg::kGravelEdge:
    case msg::kSoilEdge:
    case msg::kGuardRail:
    case msg::kCurb:
    case msg::kStructure: return sensor::LaneType::RoadEdge;
    default: return sensor::LaneType::Solid;  // solid, unknown and other: painted
  }
}

bool finite(const msg::Vector3d& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }
bool finite(const msg::Orientation3d& o) {
  return std::isfinite(o.roll) && std::isfinite(o.pitch) && std::isfinite(o.yaw);
}
bool finite(const msg::Dimension3d& d) {
  return std::isfinite(d.length) && std::isfinite(d.width) && std::isfinite(d.height);
}
Eigen::Vector3d vec(const msg::Vector3d& v) { return {v.x, v.y, v.z}; }

}  // namespace

int scenery_class_from_osi(const msg::StationaryObject& o) {
  namespace c = pgm::cls;
  switch (o.type) {
    case msg::kBuilding: return c::building;
    case msg::kPole:
    case msg::kDelineator:
    case msg::kVerticalStructure:
    case msg::kReflectiveStructure:
    case msg::kEmittingStructure: return c::pole;  // street lights, reflector posts
    case msg::kTree: return c::trunk;               // a trunk under a crown (see read_stationary_objects)
    case msg::kBarrier: return c::fence;            // guard rails, barriers
    case msg::kVegetation: return c::vegetation;
    case msg::kCurbstone: return c::sidewalk;       // SemanticKITTI labels kerbs sidewalk
    case msg::kSpeedBump: return c::road;
    case msg::kBridge:
    case msg::kWall:
    case msg::kRectangularStructure:
    case msg::kOverheadStructure: return c::other_structure;
    case msg::kStationaryOther:
    case msg::kStationaryUnknown: return o.material == msg::kMud ? c::terrain : c::other_object;
    default: return c::other_object;  // pylons, construction site elements
  }
}

int scenery_material_from_osi(const msg::StationaryObject& o, int class_id) {
  namespace m = pgm::material;
  if (o.type == msg::kReflectiveStructure) return m::retroreflective_sign;
  switch (o.material) {
    case msg::kConcrete:
    case msg::kStone: return m::concrete;
    case msg::kMetal: return m::metal;
    case msg::kGlas: return m::glass;
    case msg::kMud: return m::terrain;
    default: return pgm::default_material(class_id);  // wood, plastic, other, unknown: the class's own
  }
}

const msg::MountingPosition* sensor_mount(const msg::SensorView& view, std::string& field) {
  if (view.has & msg::bit(4)) {
    field = "mounting_position";
    return &view.mounting_position;
  }
  for (std::size_t i = 0; i < view.lidar_sensor_view.size(); ++i) {
    const auto& c = view.lidar_sensor_view[i];
    if (c.has & msg::bit(2)) {
      field = "lidar_sensor_view[" + std::to_string(i) + "].view_configuration.mounting_position";
      return &c.mounting_position;
    }
  }
  field.clear();
  return nullptr;
}

namespace {

// One error naming the trace, the message and the field.
struct FieldError {
  const std::string& source;
  long index;
  Error operator()(const std::string& field, const std::string& what) const {
    return Error(source + ": message " + std::to_string(index) + ": " + field + ": " + what);
  }
};

bool finite_base(const msg::BaseMoving& b) {
  return finite(b.position) && finite(b.orientation) && finite(b.dimension) && finite(b.velocity) &&
         finite(b.acceleration);
}

// The ego frame from the host: its rear axle on the ground, yawed with the host. Returns the
// axle's height above the ground, which mounts (given from the rear axle in OSI) are raised by.
double read_host(const msg::GroundTruth& gt, const FieldError& fail, SceneFrame& out) {
  const msg::MovingObject* host = nullptr;
  for (const auto& o : gt.moving_object)
    if (o.id.value == out.host_id) host = &o;
  if (!host)
    throw fail("host_vehicle_id", std::to_string(out.host_id) + " is not among global_ground_truth.moving_object");
  const auto& hb = host->base;
  if (!finite_base(hb)) throw fail("host base", "not finite");
  const sensor::Pose host_box = pose_from_osi(hb.position, hb.orientation);
  const auto& r = host->bbcenter_to_rear;
  const Eigen::Vector3d rear_axle = sensor::apply(host_box, vec(r));
  const double axle_height = r.z + hb.dimension.height / 2;
  const double yaw = hb.orientation.yaw;
  out.map.ego_in_map = sensor::make_pose(rear_axle - axle_height * Eigen::Vector3d::UnitZ(), 0, 0, yaw);
  out.host_velocity = vec(hb.velocity);
  out.host_acceleration = vec(hb.acceleration);
  return axle_height;
}

sensor::Pose mount_in_ego(const msg::MountingPosition& m, double axle_height) {
  return sensor::make_pose(Eigen::Vector3d(m.position.x, m.position.y, m.position.z + axle_height),
                           m.orientation.roll, m.orientation.pitch, m.orientation.yaw);
}

// One detector per lidar_sensor_view (at least one): its own sensor_id and mount where its view
// configuration gives them, else the SensorView's.
void read_detectors(const msg::SensorView& view, const msg::MountingPosition& mp, double axle_height,
                    const FieldError& fail, SceneFrame& out) {
  out.detectors.resize(std::max<std::size_t>(1, view.lidar_sensor_view.size()));
  for (std::size_t i = 0; i < out.detectors.size(); ++i) {
    Detector& d = out.detectors[i];
    d.sensor_id = view.sensor_id;
    d.mounting_position = mp;
    if (i >= view.lidar_sensor_view.size()) break;
    const auto& c = view.lidar_sensor_view[i];
    if (c.has & msg::bit(1)) d.sensor_id = c.sensor_id;
    if (c.has & msg::bit(2)) {
      const auto& m = c.mounting_position;
      if (!finite(m.position) || !finite(m.orientation))
        throw fail("lidar_sensor_view[" + std::to_string(i) + "].view_configuration.mounting_position", "not finite");
      d.mounting_position = m;
    }
  }
  for (Detector& d : out.detectors) d.mount = mount_in_ego(d.mounting_position, axle_height);
}

void read_moving_objects(const msg::GroundTruth& gt, const FieldError& fail, IdMap& ids, SceneFrame& out) {
  out.map.objects.clear();
  for (std::size_t i = 0; i < gt.moving_object.size(); ++i) {
    const auto& o = gt.moving_object[i];
    const std::string field = "global_ground_truth.moving_object[" + std::to_string(i) + "]";
    if (!(o.has & msg::bit(1))) throw fail(field + ".id", "missing");
    if (o.id.value == out.host_id) continue;
    if (!(o.has & msg::bit(2)) || !(o.base.has & msg::bit(2))) throw fail(field + ".base.position", "missing");
    const auto& b = o.base;
    if (!finite_base(b)) throw fail(field + ".base", "not finite");
    if (!(b.dimension.length > 0 && b.dimension.width > 0 && b.dimension.height > 0))
      throw fail(field + ".base.dimension", "must be positive");
    sensor::Object& obj = out.map.objects.emplace_back();
    obj.id = ids.to_model(o.id.value);
    obj.cls = class_from_osi(o);
    obj.material = sensor::default_material(obj.cls);
    obj.position = vec(b.position);
    obj.velocity = vec(b.velocity);
    obj.acceleration = vec(b.acceleration);
    obj.size = {b.dimension.length, b.dimension.width, b.dimension.height};
    obj.heading = b.orientation.yaw;
  }
}

// Stationary objects become scenery boxes (sensor/scenery.h) in the map frame, as a scenario's
// "scenery" does: never tracked or reported, but they occlude and return points. Boxes are
// yaw-only, as every box of the model is: roll and pitch are not used.
void read_stationary_objects(const msg::GroundTruth& gt, const FieldError& fail, SceneFrame& out) {
  out.map.scenery.clear();
  if (gt.stationary_object.size() > static_cast<std::size_t>(sensor::kMaxSceneryElements))
    throw fail("global_ground_truth.stationary_object",
               std::to_string(gt.stationary_object.size()) + " objects, at most " +
                   std::to_string(sensor::kMaxSceneryElements) + " (no street holds more)");
  for (std::size_t i = 0; i < gt.stationary_object.size(); ++i) {
    const auto& o = gt.stationary_object[i];
    const std::string field = "global_ground_truth.stationary_object[" + std::to_string(i) + "]";
    if (!(o.has & msg::bit(2)) || !(o.base.has & msg::bit(2))) throw fail(field + ".base.position", "missing");
    const auto& b = o.base;
    if (!finite(b.position) || !finite(b.orientation) || !finite(b.dimension)) throw fail(field + ".base", "not finite");
    if (!(b.dimension.length > 0 && b.dimension.width > 0 && b.dimension.height > 0))
      throw fail(field + ".base.dimension", "must be positive (length, width and height)");
    const Eigen::Vector3d foot(b.position.x, b.position.y, b.position.z - 0.5 * b.dimension.height);
    const int element = static_cast<int>(i);
    if (o.type == msg::kTree) {
      // The box holds the crown; the trunk is the lower 40 % of the height.
      sensor::TreeShape t;
      t.crown_diameter = 0.5 * (b.dimension.length + b.dimension.width);
      t.crown_height = 0.6 * b.dimension.height;
      t.trunk_height = b.dimension.height - t.crown_height;
      t.trunk_diameter = std::clamp(0.1 * t.crown_diameter, 0.1, 0.6);
      sensor::add_scenery_tree(out.map.scenery, foot, t, element);
      continue;
    }
    const int cls = scenery_class_from_osi(o);
    sensor::add_scenery_box(out.map.scenery, foot, {b.dimension.length, b.dimension.width, b.dimension.height},
                            b.orientation.yaw, cls, scenery_material_from_osi(o, cls), element);
  }
  if (out.map.scenery.size() > static_cast<std::size_t>(sensor::kMaxSceneryBoxes))  // a tree is 5 boxes
    throw fail("global_ground_truth.stationary_object",
               std::to_string(out.map.scenery.size()) + " scenery boxes, at most " +
                   std::to_string(sensor::kMaxSceneryBoxes));
}

// At most 0.5 m between points, as scenario lanes (sensor/scenario.h), which are at most 100 km
// long: points 1e300 m apart made an infinite count (UBSan, the osi_trace fuzz target), 1e7 m
// apart 2e7 points.
void read_boundary_points(const msg::LaneBoundary& lb, std::size_t i, const FieldError& fail,
                          sensor::LanePolyline& lane) {
  double length = 0;
  for (std::size_t k = 0; k < lb.boundary_line.size(); ++k) {
    const auto& p = lb.boundary_line[k];
    const std::string field =
        "global_ground_truth.lane_boundary[" + std::to_string(i) + "].boundary_line[" + std::to_string(k) + "]";
    if (!finite(p)) throw fail(field, "not finite");
    const Eigen::Vector3d q = vec(p);
    if (!lane.points.empty()) {
      const Eigen::Vector3d a = lane.points.back(), d = q - a;
      length += d.norm();
      if (!(length <= kMaxLaneLength))
        throw fail(field, "the lane is " + std::to_string(length) + " m long up to here, at most " +
                              std::to_string(static_cast<int>(kMaxLaneLength)) + " m");
      // (a tolerance, so points already 0.5 m apart are not split again)
      const int n = std::max(1, static_cast<int>(std::ceil(d.norm() / 0.5 - 1e-6)));
      for (int s = 1; s < n; ++s) lane.points.push_back(a + d * (static_cast<double>(s) / n));
    }
    lane.points.push_back(q);
  }
}

void read_lane_boundaries(const msg::GroundTruth& gt, const FieldError& fail, IdMap& ids, SceneFrame& out) {
  out.map.lanes.clear();
  for (std::size_t i = 0; i < gt.lane_boundary.size(); ++i) {
    const auto& lb = gt.lane_boundary[i];
    bool drawn = true;
    const sensor::LaneType type = lane_type(lb, drawn);
    if (!drawn || lb.boundary_line.size() < 2) continue;
    if (!(lb.has & msg::bit(1)))
      throw fail("global_ground_truth.lane_boundary[" + std::to_string(i) + "].id", "missing");
    sensor::LanePolyline& lane = out.map.lanes.emplace_back();
    lane.id = ids.to_model(lb.id.value);
    lane.type = type;
    read_boundary_points(lb, i, fail, lane);
  }
}

}  // namespace

void scene_from_sensor_view(const msg::SensorView& view, long index, const std::string& source, IdMap& ids,
                            SceneFrame& out) {
  const FieldError fail{source, index};
  if (!(view.has & msg::bit(7))) throw fail("global_ground_truth", "missing (a SensorView needs ground truth)");
  const msg::GroundTruth& gt = view.global_ground_truth;
  if (view.has & msg::bit(8)) out.host_id = view.host_vehicle_id.value;
  else if (gt.has & msg::bit(3)) out.host_id = gt.host_vehicle_id.value;
  else throw fail("host_vehicle_id", "missing (neither the SensorView nor its ground truth names the host)");
  std::string mount_field;
  const msg::MountingPosition* mount = sensor_mount(view, mount_field);
  if (!mount)
    throw fail("mounting_position",
               "missing (neither the SensorView nor any lidar_sensor_view[].view_configuration gives it)");
  const auto& mp = *mount;
  if (!finite(mp.position) || !finite(mp.orientation)) throw fail(mount_field, "not finite");

  out.sensor_id = view.sensor_id;
  out.mounting_position = mp;
  out.timestamp = (view.has & msg::bit(2)) ? view.timestamp : gt.timestamp;
  out.time = seconds(out.timestamp);
  out.map.time = out.time;

  const double axle_height = read_host(gt, fail, out);  // the host first: it defines the ego frame
  out.mount = mount_in_ego(mp, axle_height);
  read_detectors(view, mp, axle_height, fail, out);
  read_moving_objects(gt, fail, ids, out);
  read_stationary_objects(gt, fail, out);
  read_lane_boundaries(gt, fail, ids, out);
}

}  // namespace lidarsim::osi
