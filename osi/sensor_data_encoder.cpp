// encode_sensor_data (osi/sensor_data.h): build_sensor_data's message written as wire bytes.
// Every body below emits its message's fields in field-number order (the order libprotobuf
// writes), each with the field's name and number from osi/proto/osi3_subset.proto; a field
// build_sensor_data sets is emitted whatever its value (proto2 keeps a presence bit).
#include <algorithm>
#include <cmath>
#include <string>
#include <string_view>
#include <vector>

#include "common/error.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view_decoder.h"
#include "osi/wire.h"
#include "sensor/frames.h"

namespace lidarsim::osi {

namespace {

using wire::put_f64;
using wire::put_tag;
using wire::put_varint;

// Submessages echoed from the SensorView (timestamp, ids, mounts) as libprotobuf serializes them
// (osi::wire_bytes), so fields we do not know survive as they do through build_sensor_data; a few
// dozen bytes each.
struct Echoes {
  std::string timestamp, sensor_id, mounting_position;
  std::vector<std::string> detector_sensor_id, detector_mounting_position;
};

template <class Sink>
void vector3d(Sink& o, const Eigen::Vector3d& v) {  // Vector3d: x (1), y (2), z (3)
  o.f64(1, v.x());
  o.f64(2, v.y());
  o.f64(3, v.z());
}

template <class Sink>
void version(Sink& o) {  // InterfaceVersion: version_major (1), version_minor (2), version_patch (3)
  o.uint(1, kOsiVersion[0]);
  o.uint(2, kOsiVersion[1]);
  o.uint(3, kOsiVersion[2]);
}

template <class Sink>
void entity_header(Sink& o, const Echoes& e, std::uint64_t cycle) {
  o.bytes(1, e.timestamp);  // DetectedEntityHeader.measurement_time
  o.uint(2, cycle);         // cycle_counter
  o.sint(3, msg::kDataQualifierAvailable);  // data_qualifier
}

struct ObjectFrame {  // what moving_object needs besides the object
  const Echoes& echoes;
  const IdMap& ids;
  Eigen::Vector3d host_velocity, host_acceleration;  // sensor frame
};

template <class Sink>
void moving_object(Sink& o, const ReportedDetection& d, const ObjectFrame& f) {
  const sensor::Object& obj = d.object;
  o.message(1, [&](auto& h) {  // DetectedMovingObject.header: DetectedItemHeader
    h.message(1, [&](auto& id) { id.uint(1, osi_tracking_id(obj.id)); });  // tracking_id.value
    if (d.truth_id >= 0 && f.ids.known(d.truth_id))
      h.message(2, [&](auto& id) { id.uint(1, f.ids.to_osi(d.truth_id)); });  // ground_truth_id[0].value
    h.f64(3, std::clamp(obj.score, 0.0, 1.0));                                 // existence_probability
    h.sint(5, d.coasting ? msg::kMeasurementStatePredicted
                         : msg::kMeasurementStateMeasured);  // measurement_state
    h.bytes(6, f.echoes.sensor_id);                                                // sensor_id[0]
  });
  o.message(2, [&](auto& b) {  // base: BaseMoving
    b.message(1, [&](auto& v) {  // dimension: length (1), width (2), height (3)
      v.f64(1, obj.size.x());
      v.f64(2, obj.size.y());
      v.f64(3, obj.size.z());
    });
    b.message(2, [&](auto& v) { vector3d(v, obj.position); });  // position
    b.message(3, [&](auto& v) {                                 // orientation: roll (1), pitch (2), yaw (3)
      v.f64(1, 0.0);
      v.f64(2, 0.0);
      v.f64(3, sensor::wrap_pi(obj.heading));
    });
    b.message(4, [&](auto& v) { vector3d(v, obj.velocity - f.host_velocity); });          // velocity
    b.message(5, [&](auto& v) { vector3d(v, obj.acceleration - f.host_acceleration); });  // acceleration
  });
  o.sint(4, msg::kReferencePointCenter);  // reference_point
  o.message(8, [&](auto& c) {                                     // candidate[0]
    const auto type = osi_type(obj.cls);
    c.f64(1, 1.0);   // probability
    c.sint(2, type);  // type
    if (type == msg::kTypeVehicle)
      c.message(3, [&](auto& v) { v.sint(1, osi_vehicle_type(obj.cls)); });  // vehicle_classification.type
  });
}

template <class Sink>
void lane_boundary(Sink& o, const sensor::LanePolynomial& p, const IdMap& ids) {
  const std::uint64_t id = osi_id_of(p.id, ids);
  o.message(1, [&](auto& h) {  // DetectedLaneBoundary.header: DetectedItemHeader
    h.message(1, [&](auto& v) { v.uint(1, id); });                   // tracking_id.value
    if (id != kNoObject) h.message(2, [&](auto& v) { v.uint(1, id); });  // ground_truth_id[0].value
    h.f64(3, 1.0);                                                     // existence_probability
    h.sint(5, msg::kMeasurementStateMeasured);   // measurement_state
  });
  o.message(2, [&](auto& c) {  // candidate[0]: probability (1), classification (2) { type (1) }
    c.f64(1, 1.0);
    c.message(2, [&](auto& k) { k.sint(1, osi_lane_type(p.type)); });
  });
  const int n = lane_point_count(p);
  for (int k = 0; k < n; ++k) {
    const Eigen::Vector2d xy = lane_point(p, k, n);
    o.message(3, [&](auto& b) {    // boundary_line[k]: BoundaryPoint
      b.message(1, [&](auto& v) {  // position
        v.f64(1, xy.x());
        v.f64(2, xy.y());
        v.f64(3, 0.0);
      });
    });
  }
}

// One detector's detections, the hot loop: per return LidarDetectionData.detection (2) =
// { existence_probability (1), object_id (2) { value (1) }, position (3) { distance (1),
// azimuth (2), elevation (3) }, intensity (7) }: 50 bytes plus the id's varint, so the size is
// known without measuring through the nesting.
class Detections {
 public:
  Detections(const CloudRef& cloud, const IdMap& ids) : cloud_(cloud) {
    if (cloud.size == 0) return;
    azimuth_ = column_azimuths(*cloud.layout);
    osi_of_model_.resize(ids.size());
    for (std::size_t m = 0; m < ids.size(); ++m) osi_of_model_[m] = ids.to_osi(static_cast<int>(m));
    for (std::size_t i = 0; i < cloud.size; ++i) bytes_ += 2 + kFixedBytes + wire::varint_size(osi_id(i));
  }
  std::size_t bytes() const { return bytes_; }

  char* write(char* p) const {
    if (cloud_.size == 0) return p;  // then the layout may be null (no point cloud)
    const int W = cloud_.layout->columns;
    for (std::size_t i = 0; i < cloud_.size; ++i) {
      const std::uint64_t id = osi_id(i);
      const std::size_t id_bytes = wire::varint_size(id);
      const int row = cloud_.cell[i] / W, col = cloud_.cell[i] % W;
      p = put_varint(put_tag(p, 2, wire::kLengthDelimited), kFixedBytes + id_bytes);
      p = put_f64(p, 1, 1.0);
      p = put_varint(put_tag(p, 2, wire::kLengthDelimited), 1 + id_bytes);
      p = put_varint(put_tag(p, 1, wire::kVarint), id);
      p = put_varint(put_tag(p, 3, wire::kLengthDelimited), 27);
      p = put_f64(p, 1, cloud_.range[i]);
      p = put_f64(p, 2, azimuth_[static_cast<std::size_t>(col)]);
      p = put_f64(p, 3, cloud_.layout->elevations_rad[static_cast<std::size_t>(row)]);
      p = put_f64(p, 7, 100.0 * cloud_.intensity[i]);
    }
    return p;
  }

 private:
  // existence 9, object_id tag + length + value tag 3, position tag + length + 3 x 9 = 29, intensity 9.
  static constexpr std::size_t kFixedBytes = 9 + 3 + 29 + 9;
  std::uint64_t osi_id(std::size_t i) const {
    const int m = static_cast<int>(std::lround(cloud_.object_id[i]));  // as build_sensor_data rounds
    return m >= 0 && static_cast<std::size_t>(m) < osi_of_model_.size() ? osi_of_model_[static_cast<std::size_t>(m)]
                                                                         : kNoObject;
  }
  const CloudRef& cloud_;
  std::vector<double> azimuth_;
  std::vector<std::uint64_t> osi_of_model_;
  std::size_t bytes_ = 0;
};

template <class Sink>
void lidar_sensor(Sink& o, const Echoes& e, std::size_t i, const CloudRef& cloud, const Detections& detections,
                  std::uint64_t cycle) {
  o.message(1, [&](auto& h) {  // LidarDetectionData.header: SensorDetectionHeader
    h.bytes(1, e.timestamp);   // measurement_time
    h.uint(2, cycle);          // cycle_counter
    h.bytes(3, e.detector_mounting_position[i]);                          // mounting_position
    h.sint(5, msg::kDataQualifierAvailable);     // data_qualifier
    h.uint(6, static_cast<std::uint32_t>(cloud.size));                    // number_of_valid_detections
    h.bytes(7, e.detector_sensor_id[i]);                                  // sensor_id
  });
  o.raw(detections.bytes(), [&](char* p) { return detections.write(p); });  // detection[]
}

}  // namespace

void encode_sensor_data(const SceneFrame& scene, const std::vector<ReportedDetection>& objects,
                        const std::vector<sensor::LanePolynomial>& lanes, const std::vector<CloudRef>& clouds,
                        const IdMap& ids, std::uint64_t cycle, std::string& out, std::size_t prefix) {
  if (clouds.size() != scene.detectors.size())
    throw Error("encode_sensor_data: clouds: " + std::to_string(clouds.size()) + " for " +
                std::to_string(scene.detectors.size()) + " detectors");
  Echoes e;
  e.timestamp = wire_bytes(scene.timestamp);
  e.sensor_id = wire_bytes(scene.sensor_id);
  e.mounting_position = wire_bytes(scene.mounting_position);
  for (const Detector& d : scene.detectors) {
    e.detector_sensor_id.push_back(wire_bytes(d.sensor_id));
    e.detector_mounting_position.push_back(wire_bytes(d.mounting_position));
  }
  // Velocities and accelerations relative to the sensor, as build_sensor_data gives them.
  const sensor::Pose map_from_sensor = sensor::compose(scene.map.ego_in_map, scene.mount);
  const ObjectFrame frame{e, ids, map_from_sensor.rotation.transpose() * scene.host_velocity,
                          map_from_sensor.rotation.transpose() * scene.host_acceleration};
  std::vector<Detections> detections;
  detections.reserve(clouds.size());
  for (const CloudRef& c : clouds) detections.emplace_back(c, ids);

  const auto sensor_data = [&](auto& o) {
    o.message(1, [&](auto& v) { version(v); });  // SensorData.version
    o.bytes(2, e.timestamp);                     // timestamp
    o.bytes(5, e.sensor_id);                     // sensor_id
    o.bytes(6, e.mounting_position);             // mounting_position
    o.bytes(9, e.timestamp);                     // last_measurement_time
    o.message(12, [&](auto& h) { entity_header(h, e, cycle); });  // moving_object_header
    for (const auto& d : objects) o.message(13, [&](auto& m) { moving_object(m, d, frame); });  // moving_object[]
    o.message(20, [&](auto& h) { entity_header(h, e, cycle); });  // lane_boundary_header
    for (const auto& p : lanes) o.message(21, [&](auto& l) { lane_boundary(l, p, ids); });  // lane_boundary[]
    o.message(26, [&](auto& f) {                                // feature_data: FeatureData
      f.message(1, [&](auto& v) { version(v); });               // version
      for (std::size_t i = 0; i < clouds.size(); ++i)          // lidar_sensor[i]
        f.message(3, [&](auto& l) { lidar_sensor(l, e, i, clouds[i], detections[i], cycle); });
    });
  };
  const std::size_t size = wire::measure(sensor_data);
  out.resize(prefix + size);
  wire::Writer w(out.data() + prefix);
  sensor_data(w);
  if (w.end() != out.data() + out.size())
    throw Error("encode_sensor_data: wrote " + std::to_string(w.end() - (out.data() + prefix)) + " bytes of the " +
                std::to_string(size) + " measured");
}

}  // namespace lidarsim::osi
