#include "osi/sensor_view.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "sensor/frames.h"
#include "sensor/scenario.h"

namespace lidarsim::osi {

int IdMap::to_model(std::uint64_t osi_id) {
  const auto [it, inserted] = to_model_.try_emplace(osi_id, static_cast<int>(to_osi_.size()));
  if (inserted) to_osi_.push_back(osi_id);
  return it->second;
}

double seconds(const osi3::Timestamp& t) { return static_cast<double>(t.seconds()) + t.nanos() * 1e-9; }

void set_timestamp(double s, osi3::Timestamp& t) {
  auto whole = static_cast<std::int64_t>(std::floor(s));
  auto nanos = static_cast<std::int64_t>(std::llround((s - static_cast<double>(whole)) * 1e9));
  if (nanos >= 1000000000) {
    ++whole;
    nanos -= 1000000000;
  }
  t.set_seconds(whole);
  t.set_nanos(static_cast<std::uint32_t>(nanos));
}

sensor::Pose pose_from_osi(const osi3::Vector3d& p, const osi3::Orientation3d& o) {
  return sensor::make_pose(Eigen::Vector3d(p.x(), p.y(), p.z()), o.roll(), o.pitch(), o.yaw());
}

sensor::ObjectClass class_from_osi(const osi3::MovingObject& o) {
  using VT = osi3::MovingObject::VehicleClassification;
  switch (o.type()) {
    case osi3::MovingObject::TYPE_PEDESTRIAN: return sensor::ObjectClass::Pedestrian;
    case osi3::MovingObject::TYPE_VEHICLE:
      switch (o.vehicle_classification().type()) {
        case VT::TYPE_DELIVERY_VAN: return sensor::ObjectClass::Van;
        case VT::TYPE_HEAVY_TRUCK:
        case VT::TYPE_SEMITRAILER:
        case VT::TYPE_TRAILER: return sensor::ObjectClass::Truck;
        case VT::TYPE_BUS:
        case VT::TYPE_TRAM:
        case VT::TYPE_TRAIN: return sensor::ObjectClass::Bus;
        case VT::TYPE_MOTORBIKE: return sensor::ObjectClass::Motorcycle;
        case VT::TYPE_BICYCLE: return sensor::ObjectClass::Cyclist;
        case VT::TYPE_WHEELCHAIR: return sensor::ObjectClass::Misc;
        default: return sensor::ObjectClass::Car;
      }
    default: return sensor::ObjectClass::Misc;
  }
}

osi3::MovingObject::Type osi_type(sensor::ObjectClass c) {
  switch (c) {
    case sensor::ObjectClass::Pedestrian: return osi3::MovingObject::TYPE_PEDESTRIAN;
    case sensor::ObjectClass::Misc: return osi3::MovingObject::TYPE_OTHER;
    default: return osi3::MovingObject::TYPE_VEHICLE;
  }
}

osi3::MovingObject::VehicleClassification::Type osi_vehicle_type(sensor::ObjectClass c) {
  using VT = osi3::MovingObject::VehicleClassification;
  switch (c) {
    case sensor::ObjectClass::Car: return VT::TYPE_MEDIUM_CAR;
    case sensor::ObjectClass::Van: return VT::TYPE_DELIVERY_VAN;
    case sensor::ObjectClass::Truck: return VT::TYPE_HEAVY_TRUCK;
    case sensor::ObjectClass::Bus: return VT::TYPE_BUS;
    case sensor::ObjectClass::Motorcycle: return VT::TYPE_MOTORBIKE;
    case sensor::ObjectClass::Cyclist: return VT::TYPE_BICYCLE;
    default: return VT::TYPE_OTHER;
  }
}

namespace {

// Longest lane accepted, as for scenario lanes (sensor/scenario.cpp).
constexpr double kMaxLaneLength = 100000;  // m

sensor::LaneType lane_type(const osi3::LaneBoundary& b, bool& drawn) {
  using C = osi3::LaneBoundary::Classification;
  drawn = true;
  switch (b.classification().type()) {
    case C::TYPE_NO_LINE: drawn = false; return sensor::LaneType::Solid;
    case C::TYPE_DASHED_LINE:
    case C::TYPE_BOTTS_DOTS: return sensor::LaneType::Dashed;
    case C::TYPE_ROAD_EDGE:
    case C::TYPE_SNOW_EDGE:
    case C::TYPE_GRASS_EDGE:
    case C::TYPE_GRAVEL_EDGE:
    case C::TYPE_SOIL_EDGE:
    case C::TYPE_GUARD_RAIL:
    case C::TYPE_CURB:
    case C::TYPE_STRUCTURE: return sensor::LaneType::RoadEdge;
    default: return sensor::LaneType::Solid;  // solid, unknown and other: painted
  }
}

bool finite(const osi3::Vector3d& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); }
bool finite(const osi3::Orientation3d& o) {
  return std::isfinite(o.roll()) && std::isfinite(o.pitch()) && std::isfinite(o.yaw());
}
bool finite(const osi3::Dimension3d& d) {
  return std::isfinite(d.length()) && std::isfinite(d.width()) && std::isfinite(d.height());
}

}  // namespace

const osi3::MountingPosition* sensor_mount(const osi3::SensorView& view, std::string& field) {
  if (view.has_mounting_position()) {
    field = "mounting_position";
    return &view.mounting_position();
  }
  for (int i = 0; i < view.lidar_sensor_view_size(); ++i) {
    const auto& c = view.lidar_sensor_view(i).view_configuration();
    if (c.has_mounting_position()) {
      field = "lidar_sensor_view[" + std::to_string(i) + "].view_configuration.mounting_position";
      return &c.mounting_position();
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

bool finite_base(const osi3::BaseMoving& b) {
  return finite(b.position()) && finite(b.orientation()) && finite(b.dimension()) && finite(b.velocity()) &&
         finite(b.acceleration());
}

// The ego frame from the host: its rear axle on the ground, yawed with the host. Returns the
// axle's height above the ground, which mounts (given from the rear axle in OSI) are raised by.
double read_host(const osi3::GroundTruth& gt, const FieldError& fail, SceneFrame& out) {
  const osi3::MovingObject* host = nullptr;
  for (const auto& o : gt.moving_object())
    if (o.id().value() == out.host_id) host = &o;
  if (!host)
    throw fail("host_vehicle_id", std::to_string(out.host_id) + " is not among global_ground_truth.moving_object");
  const auto& hb = host->base();
  if (!finite_base(hb)) throw fail("host base", "not finite");
  const sensor::Pose host_box = pose_from_osi(hb.position(), hb.orientation());
  const auto& r = host->vehicle_attributes().bbcenter_to_rear();
  const Eigen::Vector3d rear_axle = sensor::apply(host_box, Eigen::Vector3d(r.x(), r.y(), r.z()));
  const double axle_height = r.z() + hb.dimension().height() / 2;
  const double yaw = hb.orientation().yaw();
  out.map.ego_in_map = sensor::make_pose(rear_axle - axle_height * Eigen::Vector3d::UnitZ(), 0, 0, yaw);
  out.host_velocity = Eigen::Vector3d(hb.velocity().x(), hb.velocity().y(), hb.velocity().z());
  out.host_acceleration = Eigen::Vector3d(hb.acceleration().x(), hb.acceleration().y(), hb.acceleration().z());
  return axle_height;
}

sensor::Pose mount_in_ego(const osi3::MountingPosition& m, double axle_height) {
  return sensor::make_pose(Eigen::Vector3d(m.position().x(), m.position().y(), m.position().z() + axle_height),
                           m.orientation().roll(), m.orientation().pitch(), m.orientation().yaw());
}

// One detector per lidar_sensor_view (at least one): its own sensor_id and mount where its view
// configuration gives them, else the SensorView's.
void read_detectors(const osi3::SensorView& view, const osi3::MountingPosition& mp, double axle_height,
                    const FieldError& fail, SceneFrame& out) {
  out.detectors.resize(static_cast<std::size_t>(std::max(1, view.lidar_sensor_view_size())));
  for (std::size_t i = 0; i < out.detectors.size(); ++i) {
    Detector& d = out.detectors[i];
    d.sensor_id = view.sensor_id();
    d.mounting_position = mp;
    if (static_cast<int>(i) >= view.lidar_sensor_view_size()) break;
    const auto& c = view.lidar_sensor_view(static_cast<int>(i)).view_configuration();
    if (c.has_sensor_id()) d.sensor_id = c.sensor_id();
    if (c.has_mounting_position()) {
      const auto& m = c.mounting_position();
      if (!finite(m.position()) || !finite(m.orientation()))
        throw fail("lidar_sensor_view[" + std::to_string(i) + "].view_configuration.mounting_position", "not finite");
      d.mounting_position = m;
    }
  }
  for (Detector& d : out.detectors) d.mount = mount_in_ego(d.mounting_position, axle_height);
}

void read_moving_objects(const osi3::GroundTruth& gt, const FieldError& fail, IdMap& ids, SceneFrame& out) {
  out.map.objects.clear();
  for (int i = 0; i < gt.moving_object_size(); ++i) {
    const auto& o = gt.moving_object(i);
    const std::string field = "global_ground_truth.moving_object[" + std::to_string(i) + "]";
    if (!o.has_id()) throw fail(field + ".id", "missing");
    if (o.id().value() == out.host_id) continue;
    if (!o.has_base() || !o.base().has_position()) throw fail(field + ".base.position", "missing");
    const auto& b = o.base();
    if (!finite_base(b)) throw fail(field + ".base", "not finite");
    if (!(b.dimension().length() > 0 && b.dimension().width() > 0 && b.dimension().height() > 0))
      throw fail(field + ".base.dimension", "must be positive");
    sensor::Object& obj = out.map.objects.emplace_back();
    obj.id = ids.to_model(o.id().value());
    obj.cls = class_from_osi(o);
    obj.material = sensor::default_material(obj.cls);
    obj.position = {b.position().x(), b.position().y(), b.position().z()};
    obj.velocity = {b.velocity().x(), b.velocity().y(), b.velocity().z()};
    obj.acceleration = {b.acceleration().x(), b.acceleration().y(), b.acceleration().z()};
    obj.size = {b.dimension().length(), b.dimension().width(), b.dimension().height()};
    obj.heading = b.orientation().yaw();
  }
}

// At most 0.5 m between points, as scenario lanes (sensor/scenario.h), which are at most 100 km
// long: points 1e300 m apart made an infinite count (UBSan, the osi_trace fuzz target), 1e7 m
// apart 2e7 points.
void read_boundary_points(const osi3::LaneBoundary& lb, int i, const FieldError& fail, sensor::LanePolyline& lane) {
  double length = 0;
  for (int k = 0; k < lb.boundary_line_size(); ++k) {
    const auto& p = lb.boundary_line(k).position();
    const std::string field =
        "global_ground_truth.lane_boundary[" + std::to_string(i) + "].boundary_line[" + std::to_string(k) + "]";
    if (!finite(p)) throw fail(field, "not finite");
    const Eigen::Vector3d q(p.x(), p.y(), p.z());
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

void read_lane_boundaries(const osi3::GroundTruth& gt, const FieldError& fail, IdMap& ids, SceneFrame& out) {
  out.map.lanes.clear();
  for (int i = 0; i < gt.lane_boundary_size(); ++i) {
    const auto& lb = gt.lane_boundary(i);
    bool drawn = true;
    const sensor::LaneType type = lane_type(lb, drawn);
    if (!drawn || lb.boundary_line_size() < 2) continue;
    if (!lb.has_id()) throw fail("global_ground_truth.lane_boundary[" + std::to_string(i) + "].id", "missing");
    sensor::LanePolyline& lane = out.map.lanes.emplace_back();
    lane.id = ids.to_model(lb.id().value());
    lane.type = type;
    read_boundary_points(lb, i, fail, lane);
  }
}

}  // namespace

void scene_from_sensor_view(const osi3::SensorView& view, long index, const std::string& source, IdMap& ids,
                            SceneFrame& out) {
  const FieldError fail{source, index};
  if (!view.has_global_ground_truth()) throw fail("global_ground_truth", "missing (a SensorView needs ground truth)");
  const osi3::GroundTruth& gt = view.global_ground_truth();
  if (view.has_host_vehicle_id()) out.host_id = view.host_vehicle_id().value();
  else if (gt.has_host_vehicle_id()) out.host_id = gt.host_vehicle_id().value();
  else throw fail("host_vehicle_id", "missing (neither the SensorView nor its ground truth names the host)");
  std::string mount_field;
  const osi3::MountingPosition* mount = sensor_mount(view, mount_field);
  if (!mount)
    throw fail("mounting_position",
               "missing (neither the SensorView nor any lidar_sensor_view[].view_configuration gives it)");
  const auto& mp = *mount;
  if (!finite(mp.position()) || !finite(mp.orientation())) throw fail(mount_field, "not finite");

  out.sensor_id = view.sensor_id();
  out.mounting_position = mp;
  out.timestamp = view.has_timestamp() ? view.timestamp() : gt.timestamp();
  out.time = seconds(out.timestamp);
  out.map.time = out.time;

  const double axle_height = read_host(gt, fail, out);  // the host first: it defines the ego frame
  out.mount = mount_in_ego(mp, axle_height);
  read_detectors(view, mp, axle_height, fail, out);
  read_moving_objects(gt, fail, ids, out);
  read_lane_boundaries(gt, fail, ids, out);
}

}  // namespace lidarsim::osi
