#pragma once
// libprotobuf as the oracle of the hand-written SensorView decoder (osi/sensor_view_decoder.h):
// the same bytes parsed both ways must be accepted by both or refused by both, and when accepted
// every field the decoder keeps must equal what the osi3 accessors give (doubles bit for bit,
// presence included), and every echoed message must re-serialize to libprotobuf's bytes. Shared by
// tests/osi/test_sensor_view_decoder.cpp and the osi_trace fuzz target.
#include <cstring>
#include <string>
#include <string_view>

#include "common/error.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_view_decoder.h"

namespace lidarsim::osi::oracle {

namespace detail {

struct Diff {
  std::string first;  // the first field that differs, empty when none
  void check(bool same, const std::string& field) {
    if (!same && first.empty()) first = field;
  }
  void f64(double a, double b, const std::string& field) { check(std::memcmp(&a, &b, 8) == 0, field); }
};

inline void vector3d(Diff& d, const msg::Vector3d& a, const osi3::Vector3d& b, const std::string& f) {
  d.f64(a.x, b.x(), f + ".x");
  d.f64(a.y, b.y(), f + ".y");
  d.f64(a.z, b.z(), f + ".z");
  d.check(((a.has & msg::bit(1)) != 0) == b.has_x() && ((a.has & msg::bit(2)) != 0) == b.has_y() &&
              ((a.has & msg::bit(3)) != 0) == b.has_z(),
          f + " (presence)");
}

inline void orientation(Diff& d, const msg::Orientation3d& a, const osi3::Orientation3d& b, const std::string& f) {
  d.f64(a.roll, b.roll(), f + ".roll");
  d.f64(a.pitch, b.pitch(), f + ".pitch");
  d.f64(a.yaw, b.yaw(), f + ".yaw");
}

// An echoed message: its bytes as we write them back against libprotobuf's.
template <class M, class P>
void echoed(Diff& d, const M& a, const P& b, const std::string& f) {
  d.check(wire_bytes(a) == b.SerializePartialAsString(), f + " (echoed bytes)");
}

inline void base(Diff& d, const msg::BaseMoving& a, const osi3::BaseMoving& b, const std::string& f) {
  d.f64(a.dimension.length, b.dimension().length(), f + ".dimension.length");
  d.f64(a.dimension.width, b.dimension().width(), f + ".dimension.width");
  d.f64(a.dimension.height, b.dimension().height(), f + ".dimension.height");
  d.check(((a.has & msg::bit(2)) != 0) == b.has_position(), f + ".position (presence)");
  vector3d(d, a.position, b.position(), f + ".position");
  orientation(d, a.orientation, b.orientation(), f + ".orientation");
  vector3d(d, a.velocity, b.velocity(), f + ".velocity");
  vector3d(d, a.acceleration, b.acceleration(), f + ".acceleration");
}

inline void stationary_objects(Diff& d, const msg::GroundTruth& a, const osi3::GroundTruth& b, const std::string& g) {
  d.check(a.stationary_object.size() == static_cast<std::size_t>(b.stationary_object_size()),
          g + ".stationary_object (count)");
  for (int i = 0; i < b.stationary_object_size() && i < static_cast<int>(a.stationary_object.size()); ++i) {
    const auto& x = a.stationary_object[static_cast<std::size_t>(i)];
    const auto& y = b.stationary_object(i);
    const std::string f = g + ".stationary_object[" + std::to_string(i) + "]";
    d.check(((x.has & msg::bit(1)) != 0) == y.has_id() && x.id.value == y.id().value(), f + ".id");
    d.check(((x.has & msg::bit(2)) != 0) == y.has_base(), f + ".base (presence)");
    d.f64(x.base.dimension.length, y.base().dimension().length(), f + ".base.dimension.length");
    d.f64(x.base.dimension.width, y.base().dimension().width(), f + ".base.dimension.width");
    d.f64(x.base.dimension.height, y.base().dimension().height(), f + ".base.dimension.height");
    d.check(((x.base.has & msg::bit(1)) != 0) == y.base().has_dimension(), f + ".base.dimension (presence)");
    d.check(((x.base.has & msg::bit(2)) != 0) == y.base().has_position(), f + ".base.position (presence)");
    vector3d(d, x.base.position, y.base().position(), f + ".base.position");
    orientation(d, x.base.orientation, y.base().orientation(), f + ".base.orientation");
    d.check(static_cast<int>(x.type) == static_cast<int>(y.classification().type()), f + ".classification.type");
    d.check(static_cast<int>(x.material) == static_cast<int>(y.classification().material()),
            f + ".classification.material");
  }
}

inline void ground_truth(Diff& d, const msg::GroundTruth& a, const osi3::GroundTruth& b) {
  const std::string g = "global_ground_truth";
  echoed(d, a.timestamp, b.timestamp(), g + ".timestamp");
  d.check(((a.has & msg::bit(3)) != 0) == b.has_host_vehicle_id() &&
              a.host_vehicle_id.value == b.host_vehicle_id().value(),
          g + ".host_vehicle_id");
  stationary_objects(d, a, b, g);
  d.check(a.moving_object.size() == static_cast<std::size_t>(b.moving_object_size()), g + ".moving_object (count)");
  for (int i = 0; i < b.moving_object_size() && i < static_cast<int>(a.moving_object.size()); ++i) {
    const auto& x = a.moving_object[static_cast<std::size_t>(i)];
    const auto& y = b.moving_object(i);
    const std::string f = g + ".moving_object[" + std::to_string(i) + "]";
    d.check(((x.has & msg::bit(1)) != 0) == y.has_id() && x.id.value == y.id().value(), f + ".id");
    d.check(((x.has & msg::bit(2)) != 0) == y.has_base(), f + ".base (presence)");
    base(d, x.base, y.base(), f + ".base");
    d.check(static_cast<int>(x.type) == static_cast<int>(y.type()), f + ".type");
    d.check(static_cast<int>(x.vehicle_type) == static_cast<int>(y.vehicle_classification().type()),
            f + ".vehicle_classification.type");
    vector3d(d, x.bbcenter_to_rear, y.vehicle_attributes().bbcenter_to_rear(),
             f + ".vehicle_attributes.bbcenter_to_rear");
  }
  d.check(a.lane_boundary.size() == static_cast<std::size_t>(b.lane_boundary_size()), g + ".lane_boundary (count)");
  for (int i = 0; i < b.lane_boundary_size() && i < static_cast<int>(a.lane_boundary.size()); ++i) {
    const auto& x = a.lane_boundary[static_cast<std::size_t>(i)];
    const auto& y = b.lane_boundary(i);
    const std::string f = g + ".lane_boundary[" + std::to_string(i) + "]";
    d.check(((x.has & msg::bit(1)) != 0) == y.has_id() && x.id.value == y.id().value(), f + ".id");
    d.check(static_cast<int>(x.type) == static_cast<int>(y.classification().type()), f + ".classification.type");
    d.check(x.boundary_line.size() == static_cast<std::size_t>(y.boundary_line_size()), f + ".boundary_line (count)");
    for (int k = 0; k < y.boundary_line_size() && k < static_cast<int>(x.boundary_line.size()); ++k)
      vector3d(d, x.boundary_line[static_cast<std::size_t>(k)], y.boundary_line(k).position(),
               f + ".boundary_line[" + std::to_string(k) + "].position");
  }
}

}  // namespace detail

// The first field where `ours` (decoded) and `theirs` (parsed by libprotobuf) differ, or "".
inline std::string first_difference(const msg::SensorView& ours, const osi3::SensorView& theirs) {
  detail::Diff d;
  const auto has = [&](int field) { return (ours.has & msg::bit(field)) != 0; };
  d.check(has(2) == theirs.has_timestamp(), "timestamp (presence)");
  detail::echoed(d, ours.timestamp, theirs.timestamp(), "timestamp");
  d.check(has(3) == theirs.has_sensor_id(), "sensor_id (presence)");
  detail::echoed(d, ours.sensor_id, theirs.sensor_id(), "sensor_id");
  d.check(has(4) == theirs.has_mounting_position(), "mounting_position (presence)");
  detail::echoed(d, ours.mounting_position, theirs.mounting_position(), "mounting_position");
  detail::vector3d(d, ours.mounting_position.position, theirs.mounting_position().position(),
                   "mounting_position.position");
  detail::orientation(d, ours.mounting_position.orientation, theirs.mounting_position().orientation(),
                      "mounting_position.orientation");
  d.check(has(7) == theirs.has_global_ground_truth(), "global_ground_truth (presence)");
  detail::ground_truth(d, ours.global_ground_truth, theirs.global_ground_truth());
  d.check(has(8) == theirs.has_host_vehicle_id() && ours.host_vehicle_id.value == theirs.host_vehicle_id().value(),
          "host_vehicle_id");
  d.check(ours.lidar_sensor_view.size() == static_cast<std::size_t>(theirs.lidar_sensor_view_size()),
          "lidar_sensor_view (count)");
  for (int i = 0; i < theirs.lidar_sensor_view_size() && i < static_cast<int>(ours.lidar_sensor_view.size()); ++i) {
    const auto& x = ours.lidar_sensor_view[static_cast<std::size_t>(i)];
    const auto& y = theirs.lidar_sensor_view(i).view_configuration();
    const std::string f = "lidar_sensor_view[" + std::to_string(i) + "].view_configuration";
    d.check(((x.has & msg::bit(1)) != 0) == y.has_sensor_id(), f + ".sensor_id (presence)");
    detail::echoed(d, x.sensor_id, y.sensor_id(), f + ".sensor_id");
    d.check(((x.has & msg::bit(2)) != 0) == y.has_mounting_position(), f + ".mounting_position (presence)");
    detail::echoed(d, x.mounting_position, y.mounting_position(), f + ".mounting_position");
  }
  return d.first;
}

// Both ways on `bytes`: "" when they agree (both refuse, or both accept with the same fields),
// else what differs. `error` gets the decoder's error when it refuses.
inline std::string compare_with_libprotobuf(std::string_view bytes, std::string* error = nullptr) {
  osi3::SensorView theirs;
  const bool parsed = theirs.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()));
  msg::SensorView ours;
  bool decoded = true;
  try {
    decode_sensor_view(bytes, "oracle", 0, ours);
  } catch (const Error& e) {
    decoded = false;
    if (error) *error = e.what();
  }
  if (parsed != decoded)
    return parsed ? "libprotobuf parses, the decoder refuses" : "the decoder accepts, libprotobuf refuses";
  return decoded ? first_difference(ours, theirs) : std::string();
}

}  // namespace lidarsim::osi::oracle
