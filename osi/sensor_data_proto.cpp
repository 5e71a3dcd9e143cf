#include "osi/sensor_data.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "sensor/frames.h"

namespace lidarsim::osi {

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

osi3::LaneBoundary::Classification::Type osi_lane_type(sensor::LaneType t) {
  using C = osi3::LaneBoundary::Classification;
  switch (t) {
    case sensor::LaneType::Dashed: return C::TYPE_DASHED_LINE;
    case sensor::LaneType::RoadEdge: return C::TYPE_ROAD_EDGE;
    default: return C::TYPE_SOLID_LINE;
  }
}

std::uint64_t osi_id_of(int model_id, const IdMap& ids) { return ids.known(model_id) ? ids.to_osi(model_id) : kNoObject; }

std::uint64_t osi_tracking_id(int track_id) {
  return track_id >= 0 ? static_cast<std::uint64_t>(track_id)
                       : kFalsePositiveIdBase + static_cast<std::uint64_t>(-static_cast<std::int64_t>(track_id));
}

int lane_point_count(const sensor::LanePolynomial& p) {
  return std::max(2, static_cast<int>(std::floor(p.x_max - p.x_min)) + 1);
}

Eigen::Vector2d lane_point(const sensor::LanePolynomial& p, int k, int n) {
  const double x = p.x_min + (p.x_max - p.x_min) * k / (n - 1);
  return {x, p.c0 + x * (p.c1 + x * (p.c2 + x * p.c3))};
}

std::vector<double> column_azimuths(const pgm::BeamLayout& layout) {
  std::vector<double> a(static_cast<std::size_t>(layout.columns));
  for (int c = 0; c < layout.columns; ++c) a[static_cast<std::size_t>(c)] = sensor::wrap_pi(layout.azimuth_of_column(c));
  return a;
}

namespace {

// Detector det's header and its cloud's detections into `lidar`.
void add_detections(const Detector& det, const osi3::Timestamp& time, const CloudRef& cloud, const IdMap& ids,
                    std::uint64_t cycle, osi3::LidarDetectionData& lidar) {
  auto* dh = lidar.mutable_header();
  *dh->mutable_measurement_time() = time;
  dh->set_cycle_counter(cycle);
  *dh->mutable_mounting_position() = det.mounting_position;
  dh->set_data_qualifier(osi3::SensorDetectionHeader::DATA_QUALIFIER_AVAILABLE);
  dh->set_number_of_valid_detections(static_cast<std::uint32_t>(cloud.size));
  *dh->mutable_sensor_id() = det.sensor_id;
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
  *out.mutable_timestamp() = scene.timestamp;
  *out.mutable_last_measurement_time() = scene.timestamp;
  *out.mutable_sensor_id() = scene.sensor_id;
  *out.mutable_mounting_position() = scene.mounting_position;

  // Velocities and accelerations relative to the sensor: BaseMoving's are relative to its parent
  // frame (the host's rotation rate is not subtracted: the model has none).
  const sensor::Pose map_from_sensor = sensor::compose(scene.map.ego_in_map, scene.mount);
  const Eigen::Vector3d host_velocity_sensor = map_from_sensor.rotation.transpose() * scene.host_velocity;
  const Eigen::Vector3d host_acceleration_sensor = map_from_sensor.rotation.transpose() * scene.host_acceleration;

  auto* oh = out.mutable_moving_object_header();
  *oh->mutable_measurement_time() = scene.timestamp;
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
    *h->add_sensor_id() = scene.sensor_id;
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
    c->set_type(osi_type(o.cls));
    if (c->type() == osi3::MovingObject::TYPE_VEHICLE)
      c->mutable_vehicle_classification()->set_type(osi_vehicle_type(o.cls));
  }

  auto* lh = out.mutable_lane_boundary_header();
  *lh->mutable_measurement_time() = scene.timestamp;
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
    c->mutable_classification()->set_type(osi_lane_type(p.type));
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
