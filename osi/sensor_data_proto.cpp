// build_sensor_data (osi/sensor_data.h): the SensorData as a libprotobuf message, the reference
// the hand-written encoder is checked against and what `lidar-infer osi --format txth` prints.
// Kept apart from the encoder so that code which only encodes (the FMU) links no libprotobuf.
#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view_decoder.h"
#include "sensor/frames.h"

namespace lidarsim::osi {

// The plain enums (osi/messages.h) carry the schema's values.
constexpr bool same(int ours, int schema) { return ours == schema; }
static_assert(same(msg::kTypeVehicle, osi3::MovingObject::TYPE_VEHICLE) &&
              same(msg::kTypeAnimal, osi3::MovingObject::TYPE_ANIMAL));
static_assert(same(msg::kMovingObjectTypeCount, osi3::MovingObject::Type_ARRAYSIZE));
static_assert(same(msg::kVehicleTypeCount, osi3::MovingObject::VehicleClassification::Type_ARRAYSIZE));
static_assert(same(msg::kWheelchair, osi3::MovingObject::VehicleClassification::TYPE_WHEELCHAIR));
static_assert(same(msg::kLaneBoundaryTypeCount, osi3::LaneBoundary::Classification::Type_ARRAYSIZE));
static_assert(same(msg::kStructure, osi3::LaneBoundary::Classification::TYPE_STRUCTURE));
static_assert(same(msg::kDataQualifierAvailable, osi3::DetectedEntityHeader::DATA_QUALIFIER_AVAILABLE) &&
              same(msg::kDataQualifierAvailable, osi3::SensorDetectionHeader::DATA_QUALIFIER_AVAILABLE));
static_assert(same(msg::kMeasurementStateMeasured, osi3::DetectedItemHeader::MEASUREMENT_STATE_MEASURED) &&
              same(msg::kMeasurementStatePredicted, osi3::DetectedItemHeader::MEASUREMENT_STATE_PREDICTED));
static_assert(same(msg::kReferencePointCenter, osi3::DetectedMovingObject::REFERENCE_POINT_CENTER));

namespace {

// An echoed message as the protobuf message it was decoded from.
template <class M, class P>
void to_proto(const M& m, P& out) {
  if (!out.ParseFromString(wire_bytes(m))) throw Error("build_sensor_data: an echoed message does not parse");
}

}  // namespace

void set_version(osi3::InterfaceVersion& v) {
  v.set_version_major(kOsiVersion[0]);
  v.set_version_minor(kOsiVersion[1]);
  v.set_version_patch(kOsiVersion[2]);
}

void set_vector(const Eigen::Vector3d& p, osi3::Vector3d& v) {
  v.set_x(p.x());
  v.set_y(p.y());
  v.set_z(p.z());
}

namespace {

// Detector det's header and its cloud's detections into `lidar`.
void add_detections(const Detector& det, const msg::Timestamp& time, const CloudRef& cloud, const IdMap& ids,
                    std::uint64_t cycle, osi3::LidarDetectionData& lidar) {
  auto* dh = lidar.mutable_header();
  to_proto(time, *dh->mutable_measurement_time());
  dh->set_cycle_counter(cycle);
  to_proto(det.mounting_position, *dh->mutable_mounting_position());
  dh->set_data_qualifier(osi3::SensorDetectionHeader::DATA_QUALIFIER_AVAILABLE);
  dh->set_number_of_valid_detections(static_cast<std::uint32_t>(cloud.size));
  to_proto(det.sensor_id, *dh->mutable_sensor_id());
  if (cloud.size == 0) return;
  const int W = cloud.layout->columns;
  lidar.mutable_detection()->Reserve(static_cast<int>(cloud.size));
  for (std::size_t i = 0; i < cloud.size; ++i) {
    auto* d = lidar.add_detection();
    const int row = cloud.cell[i] / W, col = cloud.cell[i] % W;
    d->set_existence_probability(1);
    d->mutable_object_id()->set_value(osi_id_of(static_cast<int>(std::lround(cloud.object_id[i])), ids));
    auto* p = d->mutable_position();
    p->set_distance(cloud.range[i]);
    p->set_azimuth(sensor::wrap_pi(cloud.layout->azimuth_of_column(col)));
    p->set_elevation(cloud.layout->elevations_rad[static_cast<std::size_t>(row)]);
    d->set_intensity(100.0 * cloud.intensity[i]);
  }
}

}  // namespace

void build_sensor_data(const SceneFrame& scene, const std::vector<ReportedDetection>& objects,
                       const std::vector<sensor::LanePolynomial>& lanes, const std::vector<CloudRef>& clouds,
                       const IdMap& ids, std::uint64_t cycle, osi3::SensorData& out) {
  out.Clear();
  set_version(*out.mutable_version());
  to_proto(scene.timestamp, *out.mutable_timestamp());
  to_proto(scene.timestamp, *out.mutable_last_measurement_time());
  to_proto(scene.sensor_id, *out.mutable_sensor_id());
  to_proto(scene.mounting_position, *out.mutable_mounting_position());

  // Velocities and accelerations relative to the sensor: BaseMoving's are relative to its parent
  // frame (the host's rotation rate is not subtracted: the model has none).
  const sensor::Pose map_from_sensor = sensor::compose(scene.map.ego_in_map, scene.mount);
  const Eigen::Vector3d host_velocity_sensor = map_from_sensor.rotation.transpose() * scene.host_velocity;
  const Eigen::Vector3d host_acceleration_sensor = map_from_sensor.rotation.transpose() * scene.host_acceleration;

  auto* oh = out.mutable_moving_object_header();
  to_proto(scene.timestamp, *oh->mutable_measurement_time());
  oh->set_cycle_counter(cycle);
  oh->set_data_qualifier(osi3::DetectedEntityHeader::DATA_QUALIFIER_AVAILABLE);
  for (const auto& d : objects) {
    const sensor::Object& o = d.object;
    auto* m = out.add_moving_object();
    auto* h = m->mutable_header();
    h->mutable_tracking_id()->set_value(osi_tracking_id(o.id));
    if (d.truth_id >= 0 && ids.known(d.truth_id)) h->add_ground_truth_id()->set_value(ids.to_osi(d.truth_id));
    h->set_existence_probability(std::clamp(o.score, 0.0, 1.0));
    h->set_measurement_state(d.coasting ? osi3::DetectedItemHeader::MEASUREMENT_STATE_PREDICTED
                                        : osi3::DetectedItemHeader::MEASUREMENT_STATE_MEASURED);
    to_proto(scene.sensor_id, *h->add_sensor_id());
    auto* b = m->mutable_base();
    set_vector(o.position, *b->mutable_position());
    b->mutable_orientation()->set_roll(0);
    b->mutable_orientation()->set_pitch(0);
    b->mutable_orientation()->set_yaw(sensor::wrap_pi(o.heading));
    b->mutable_dimension()->set_length(o.size.x());
    b->mutable_dimension()->set_width(o.size.y());
    b->mutable_dimension()->set_height(o.size.z());
    set_vector(o.velocity - host_velocity_sensor, *b->mutable_velocity());
    set_vector(o.acceleration - host_acceleration_sensor, *b->mutable_acceleration());
    m->set_reference_point(osi3::DetectedMovingObject::REFERENCE_POINT_CENTER);
    auto* c = m->add_candidate();
    c->set_probability(1);
    c->set_type(static_cast<osi3::MovingObject::Type>(osi_type(o.cls)));
    if (c->type() == osi3::MovingObject::TYPE_VEHICLE)
      c->mutable_vehicle_classification()->set_type(
          static_cast<osi3::MovingObject::VehicleClassification::Type>(osi_vehicle_type(o.cls)));
  }

  auto* lh = out.mutable_lane_boundary_header();
  to_proto(scene.timestamp, *lh->mutable_measurement_time());
  lh->set_cycle_counter(cycle);
  lh->set_data_qualifier(osi3::DetectedEntityHeader::DATA_QUALIFIER_AVAILABLE);
  for (const auto& p : lanes) {
    auto* l = out.add_lane_boundary();
    auto* h = l->mutable_header();
    const std::uint64_t id = osi_id_of(p.id, ids);
    h->mutable_tracking_id()->set_value(id);
    if (id != kNoObject) h->add_ground_truth_id()->set_value(id);
    h->set_existence_probability(1);
    h->set_measurement_state(osi3::DetectedItemHeader::MEASUREMENT_STATE_MEASURED);
    auto* c = l->add_candidate();
    c->set_probability(1);
    c->mutable_classification()->set_type(static_cast<osi3::LaneBoundary::Classification::Type>(osi_lane_type(p.type)));
    const int n = lane_point_count(p);
    for (int k = 0; k < n; ++k) {
      const Eigen::Vector2d xy = lane_point(p, k, n);
      auto* pt = l->add_boundary_line()->mutable_position();
      pt->set_x(xy.x());
      pt->set_y(xy.y());
      pt->set_z(0);
    }
  }

  auto* fd = out.mutable_feature_data();
  set_version(*fd->mutable_version());
  if (clouds.size() != scene.detectors.size())
    throw Error("build_sensor_data: clouds: " + std::to_string(clouds.size()) + " for " +
                std::to_string(scene.detectors.size()) + " detectors");
  for (std::size_t i = 0; i < clouds.size(); ++i)
    add_detections(scene.detectors[i], scene.timestamp, clouds[i], ids, cycle, *fd->add_lidar_sensor());
}

}  // namespace lidarsim::osi
