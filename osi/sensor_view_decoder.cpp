// decode_sensor_view (osi/sensor_view_decoder.h): one reader per message of the SensorView subset,
// each a loop over its fields matched on (field number, wire type) as osi/proto/osi3_subset.proto
// declares them. Known submessages we do not use are still read (libprotobuf parses them, so their
// bytes must be well formed); known scalars we do not use are skipped, which checks them alike.
#include "osi/sensor_view_decoder.h"

#include <cstring>

#include "common/error.h"
#include "osi/wire_reader.h"

namespace lidarsim::osi {

namespace {

using msg::bit;
using wire::key;
using wire::Reader;
using wire::Tag;
constexpr std::uint32_t V = wire::kVarint, F = wire::kFixed64, L = wire::kLengthDelimited;

// Where a reader keeps the fields it does not know: only the echoed messages keep them.
std::string* kept(bool keep, std::string& unknown) { return keep ? &unknown : nullptr; }

// A message none of whose fields we use (InterfaceVersion, orientation_rate, driver_id, ...):
// all its known fields are scalars, so skipping every field checks it as parsing would.
void read_unused(Reader& r) {
  while (r.more()) r.skip(r.tag());
}

// A closed proto2 enum: a value outside the enum goes to the unknown fields and leaves the field
// as it was; libprotobuf checks the value as an int32 (the low 32 bits of the varint).
template <class E>
void read_enum(Reader& r, const char* name, int count, E& out, std::uint32_t& has, int field) {
  const auto v = static_cast<std::int32_t>(static_cast<std::uint32_t>(r.varint(name)));
  if (v < 0 || v >= count) return;
  out = static_cast<E>(v);
  has |= bit(field);
}

void read(Reader& r, msg::Vector3d& m, bool keep) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, F): m.x = r.f64("x"), m.has |= bit(1); break;
      case key(2, F): m.y = r.f64("y"), m.has |= bit(2); break;
      case key(3, F): m.z = r.f64("z"), m.has |= bit(3); break;
      default: r.skip(t, kept(keep, m.unknown));
    }
  }
}

void read(Reader& r, msg::Orientation3d& m, bool keep) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, F): m.roll = r.f64("roll"), m.has |= bit(1); break;
      case key(2, F): m.pitch = r.f64("pitch"), m.has |= bit(2); break;
      case key(3, F): m.yaw = r.f64("yaw"), m.has |= bit(3); break;
      default: r.skip(t, kept(keep, m.unknown));
    }
  }
}

void read(Reader& r, msg::Dimension3d& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, F): m.length = r.f64("length"); break;
      case key(2, F): m.width = r.f64("width"); break;
      case key(3, F): m.height = r.f64("height"); break;
      default: r.skip(t);
    }
  }
}

void read(Reader& r, msg::Timestamp& m, bool keep) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, V): m.seconds = static_cast<std::int64_t>(r.varint("seconds")), m.has |= bit(1); break;
      case key(2, V): m.nanos = static_cast<std::uint32_t>(r.varint("nanos")), m.has |= bit(2); break;
      default: r.skip(t, kept(keep, m.unknown));
    }
  }
}

void read(Reader& r, msg::Identifier& m, bool keep) {
  while (r.more()) {
    const Tag t = r.tag();
    if (t.key() == key(1, V)) m.value = r.varint("value"), m.has |= bit(1);
    else r.skip(t, kept(keep, m.unknown));
  }
}

void read(Reader& r, msg::MountingPosition& m, bool keep) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("position", [&](Reader& s) { read(s, m.position, keep); }), m.has |= bit(1); break;
      case key(2, L):
        r.message("orientation", [&](Reader& s) { read(s, m.orientation, keep); });
        m.has |= bit(2);
        break;
      default: r.skip(t, kept(keep, m.unknown));
    }
  }
}

// The fields BaseMoving and BaseStationary share: dimension (1), position (2), orientation (3).
// False when `t` is none of them.
template <class Base>
bool read_box_field(Reader& r, const Tag& t, Base& m) {
  switch (t.key()) {
    case key(1, L): r.message("dimension", [&](Reader& s) { read(s, m.dimension); }), m.has |= bit(1); return true;
    case key(2, L): r.message("position", [&](Reader& s) { read(s, m.position, false); }), m.has |= bit(2); return true;
    case key(3, L):
      r.message("orientation", [&](Reader& s) { read(s, m.orientation, false); });
      m.has |= bit(3);
      return true;
    default: return false;
  }
}

void read(Reader& r, msg::BaseMoving& m) {
  while (r.more()) {
    const Tag t = r.tag();
    if (read_box_field(r, t, m)) continue;
    switch (t.key()) {
      case key(4, L): r.message("velocity", [&](Reader& s) { read(s, m.velocity, false); }), m.has |= bit(4); break;
      case key(5, L):
        r.message("acceleration", [&](Reader& s) { read(s, m.acceleration, false); });
        m.has |= bit(5);
        break;
      case key(6, L): r.message("orientation_rate", read_unused); break;
      default: r.skip(t);
    }
  }
}

// MovingObject.VehicleAttributes: only bbcenter_to_rear (4) is used.
void read_vehicle_attributes(Reader& r, msg::Vector3d& bbcenter_to_rear) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("driver_id", read_unused); break;
      case key(4, L): r.message("bbcenter_to_rear", [&](Reader& s) { read(s, bbcenter_to_rear, false); }); break;
      case key(5, L): r.message("bbcenter_to_front", read_unused); break;
      default: r.skip(t);  // radius_wheel, number_wheels, ground_clearance
    }
  }
}

// MovingObject.VehicleClassification: type (1); trailer_id (4) is checked.
void read_vehicle_classification(Reader& r, msg::MovingObject& m) {
  std::uint32_t has = 0;
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, V): read_enum(r, "type", msg::kVehicleTypeCount, m.vehicle_type, has, 1); break;
      case key(4, L): r.message("trailer_id", read_unused); break;
      default: r.skip(t);  // has_trailer
    }
  }
}

void read(Reader& r, msg::MovingObject& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("id", [&](Reader& s) { read(s, m.id, false); }), m.has |= bit(1); break;
      case key(2, L): r.message("base", [&](Reader& s) { read(s, m.base); }), m.has |= bit(2); break;
      case key(3, V): read_enum(r, "type", msg::kMovingObjectTypeCount, m.type, m.has, 3); break;
      case key(5, L):
        r.message("vehicle_attributes", [&](Reader& s) { read_vehicle_attributes(s, m.bbcenter_to_rear); });
        m.has |= bit(5);
        break;
      case key(6, L):
        r.message("vehicle_classification", [&](Reader& s) { read_vehicle_classification(s, m); });
        m.has |= bit(6);
        break;
      default: r.skip(t);  // model_reference (a proto2 string: bytes unchecked)
    }
  }
}

void read(Reader& r, msg::BaseStationary& m) {
  while (r.more()) {
    const Tag t = r.tag();
    if (!read_box_field(r, t, m)) r.skip(t);  // base_polygon, bounding_box_section: not in the subset
  }
}

void read_stationary_classification(Reader& r, msg::StationaryObject& m) {
  std::uint32_t has = 0;
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, V): read_enum(r, "type", msg::kStationaryTypeCount, m.type, has, 1); break;
      case key(2, V): read_enum(r, "material", msg::kStationaryMaterialCount, m.material, has, 2); break;
      default: r.skip(t);  // density, color, ...: not in the subset
    }
  }
}

void read(Reader& r, msg::StationaryObject& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("id", [&](Reader& s) { read(s, m.id, false); }), m.has |= bit(1); break;
      case key(2, L): r.message("base", [&](Reader& s) { read(s, m.base); }), m.has |= bit(2); break;
      case key(3, L):
        r.message("classification", [&](Reader& s) { read_stationary_classification(s, m); });
        m.has |= bit(3);
        break;
      default: r.skip(t);  // model_reference, source_reference, ...: not in the subset
    }
  }
}

// LaneBoundary.BoundaryPoint: position (1) is used; width and height are skipped.
void read_boundary_point(Reader& r, msg::Vector3d& position) {
  while (r.more()) {
    const Tag t = r.tag();
    if (t.key() == key(1, L)) r.message("position", [&](Reader& s) { read(s, position, false); });
    else r.skip(t);
  }
}

void read_classification(Reader& r, msg::LaneBoundary& m) {
  std::uint32_t has = 0;
  while (r.more()) {
    const Tag t = r.tag();
    if (t.key() == key(1, V)) read_enum(r, "type", msg::kLaneBoundaryTypeCount, m.type, has, 1);
    else r.skip(t);  // color
  }
}

void read(Reader& r, msg::LaneBoundary& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("id", [&](Reader& s) { read(s, m.id, false); }), m.has |= bit(1); break;
      case key(2, L): {
        const long i = static_cast<long>(m.boundary_line.size());
        msg::Vector3d& p = m.boundary_line.emplace_back();
        r.message("boundary_line", [&](Reader& s) { read_boundary_point(s, p); }, i);
        break;
      }
      case key(3, L):
        r.message("classification", [&](Reader& s) { read_classification(s, m); });
        m.has |= bit(3);
        break;
      default: r.skip(t);
    }
  }
}

void read(Reader& r, msg::GroundTruth& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("version", read_unused); break;
      case key(2, L): r.message("timestamp", [&](Reader& s) { read(s, m.timestamp, true); }), m.has |= bit(2); break;
      case key(3, L):
        r.message("host_vehicle_id", [&](Reader& s) { read(s, m.host_vehicle_id, false); });
        m.has |= bit(3);
        break;
      case key(4, L): {
        const long i = static_cast<long>(m.stationary_object.size());
        msg::StationaryObject& o = m.stationary_object.emplace_back();
        r.message("stationary_object", [&](Reader& s) { read(s, o); }, i);
        break;
      }
      case key(5, L): {
        const long i = static_cast<long>(m.moving_object.size());
        msg::MovingObject& o = m.moving_object.emplace_back();
        r.message("moving_object", [&](Reader& s) { read(s, o); }, i);
        break;
      }
      case key(9, L): {
        const long i = static_cast<long>(m.lane_boundary.size());
        msg::LaneBoundary& b = m.lane_boundary.emplace_back();
        r.message("lane_boundary", [&](Reader& s) { read(s, b); }, i);
        break;
      }
      default: r.skip(t);
    }
  }
}

void read(Reader& r, msg::LidarSensorViewConfiguration& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("sensor_id", [&](Reader& s) { read(s, m.sensor_id, true); }), m.has |= bit(1); break;
      case key(2, L):
        r.message("mounting_position", [&](Reader& s) { read(s, m.mounting_position, true); });
        m.has |= bit(2);
        break;
      case key(3, L): {
        msg::MountingPosition unused;
        r.message("mounting_position_rmse", [&](Reader& s) { read(s, unused, false); });
        break;
      }
      default: r.skip(t);
    }
  }
}

// LidarSensorView: view_configuration (1), merged if it comes more than once.
void read_lidar_sensor_view(Reader& r, msg::LidarSensorViewConfiguration& c) {
  while (r.more()) {
    const Tag t = r.tag();
    if (t.key() == key(1, L)) r.message("view_configuration", [&](Reader& s) { read(s, c); });
    else r.skip(t);
  }
}

void read(Reader& r, msg::SensorView& m) {
  while (r.more()) {
    const Tag t = r.tag();
    switch (t.key()) {
      case key(1, L): r.message("version", read_unused); break;
      case key(2, L): r.message("timestamp", [&](Reader& s) { read(s, m.timestamp, true); }), m.has |= bit(2); break;
      case key(3, L): r.message("sensor_id", [&](Reader& s) { read(s, m.sensor_id, true); }), m.has |= bit(3); break;
      case key(4, L):
        r.message("mounting_position", [&](Reader& s) { read(s, m.mounting_position, true); });
        m.has |= bit(4);
        break;
      case key(5, L): {
        msg::MountingPosition unused;
        r.message("mounting_position_rmse", [&](Reader& s) { read(s, unused, false); });
        break;
      }
      case key(7, L):
        r.message("global_ground_truth", [&](Reader& s) { read(s, m.global_ground_truth); });
        m.has |= bit(7);
        break;
      case key(8, L):
        r.message("host_vehicle_id", [&](Reader& s) { read(s, m.host_vehicle_id, false); });
        m.has |= bit(8);
        break;
      case key(1002, L): {
        const long i = static_cast<long>(m.lidar_sensor_view.size());
        msg::LidarSensorViewConfiguration& c = m.lidar_sensor_view.emplace_back();
        r.message("lidar_sensor_view", [&](Reader& s) { read_lidar_sensor_view(s, c); }, i);
        break;
      }
      default: r.skip(t);
    }
  }
}

template <class M>
void decode_root(std::string_view bytes, const char* type, M& out) {
  out = M{};
  const wire::Path root{nullptr, type};
  Reader r(bytes.data(), bytes.data() + bytes.size(), root);
  if constexpr (requires { read(r, out, true); }) read(r, out, true);
  else read(r, out);
}

// Echoed messages, written back: present fields in field-number order, then the unknown ones.
template <class Sink>
void put_unknown(Sink& o, const std::string& u) {
  if (u.empty()) return;
  o.raw(u.size(), [&](char* p) { return static_cast<char*>(std::memcpy(p, u.data(), u.size())) + u.size(); });
}

template <class Sink>
void put(Sink& o, const msg::Timestamp& m) {
  if (m.has & bit(1)) o.sint(1, m.seconds);
  if (m.has & bit(2)) o.uint(2, m.nanos);
  put_unknown(o, m.unknown);
}

template <class Sink>
void put(Sink& o, const msg::Identifier& m) {
  if (m.has & bit(1)) o.uint(1, m.value);
  put_unknown(o, m.unknown);
}

template <class Sink>
void put3(Sink& o, std::uint32_t has, double a, double b, double c, const std::string& unknown) {
  if (has & bit(1)) o.f64(1, a);
  if (has & bit(2)) o.f64(2, b);
  if (has & bit(3)) o.f64(3, c);
  put_unknown(o, unknown);
}

template <class Sink>
void put(Sink& o, const msg::MountingPosition& m) {
  const auto& p = m.position;
  const auto& q = m.orientation;
  if (m.has & bit(1)) o.message(1, [&](auto& s) { put3(s, p.has, p.x, p.y, p.z, p.unknown); });
  if (m.has & bit(2)) o.message(2, [&](auto& s) { put3(s, q.has, q.roll, q.pitch, q.yaw, q.unknown); });
  put_unknown(o, m.unknown);
}

template <class M>
std::string bytes_of(const M& m) {
  std::string s(wire::measure([&](auto& o) { put(o, m); }), '\0');
  wire::Writer w(s.data());
  put(w, m);
  return s;
}

}  // namespace

void decode_sensor_view(std::string_view bytes, const std::string& source, long index, msg::SensorView& out) {
  try {
    decode_root(bytes, "SensorView", out);
  } catch (const Error& e) {
    throw Error(source + ": message " + std::to_string(index) + ": " + e.what());
  }
}

void decode_message(std::string_view bytes, msg::Timestamp& out) { decode_root(bytes, "Timestamp", out); }
void decode_message(std::string_view bytes, msg::Identifier& out) { decode_root(bytes, "Identifier", out); }
void decode_message(std::string_view bytes, msg::MountingPosition& out) {
  decode_root(bytes, "MountingPosition", out);
}

std::string wire_bytes(const msg::Timestamp& m) { return bytes_of(m); }
std::string wire_bytes(const msg::Identifier& m) { return bytes_of(m); }
std::string wire_bytes(const msg::MountingPosition& m) { return bytes_of(m); }

}  // namespace lidarsim::osi
