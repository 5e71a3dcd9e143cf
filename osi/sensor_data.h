#pragma once
// Our model's output for one frame -> osi3.SensorData.
//
//   version                     kOsiVersion; timestamp and last_measurement_time = the input's
//   sensor_id, mounting_position echoed from the SensorView (host vehicle frame)
//   moving_object               one per reported object: header (tracking_id = our track id,
//                               ground_truth_id = the OSI id of the associated truth object, none
//                               for a false positive; existence_probability = the detector's
//                               score; measurement_state measured or predicted for a coasting
//                               track), base in the virtual sensor frame (box centre, yaw,
//                               dimension, velocity and acceleration relative to the sensor = over
//                               ground minus the host's), one classification candidate (probability 1)
//   lane_boundary               one per lane polynomial: points every 1 m (at least 2) over its
//                               valid range in the sensor frame, the boundary type as candidate
//   feature_data.lidar_sensor[i] the point cloud of detector i (SceneFrame::detectors, one per
//                               lidar_sensor_view): header sensor_id and mounting_position the
//                               detector's, spherical position in its frame (azimuth about z from
//                               x, elevation positive upwards), intensity in percent, object_id =
//                               the OSI id of the object hit (MAX(uint64) for road and paint)
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "osi/sensor_view.h"
#include "pgm/beam_layout.h"
#include "sensor/scene.h"

namespace osi3 {
class InterfaceVersion;
class SensorData;
class Vector3d;
}  // namespace osi3

namespace lidarsim::osi {

inline constexpr std::uint32_t kOsiVersion[3] = {3, 8, 0};  // checked against the official v3.8.0 .proto files (docs/osi.md)
inline constexpr std::uint64_t kNoObject = std::numeric_limits<std::uint64_t>::max();
// Tracking ids of false positives (our ids <= -1000) are mapped above this, real tracks keep theirs.
inline constexpr std::uint64_t kFalsePositiveIdBase = 1ull << 40;

struct ReportedDetection {
  sensor::Object object;  // sensor frame; id = track id (false positive: <= -1000)
  int truth_id = -1;      // model id of the truth object, -1 for a false positive
  bool coasting = false;
};

// Columns of the point cloud (sensor frame, one entry per return); pointers into the caller's arrays.
struct CloudRef {
  std::size_t size = 0;
  const float* range = nullptr;
  const float* intensity = nullptr;  // 0..1
  const float* object_id = nullptr;  // model ids, < 0 for road and paint
  const int* cell = nullptr;         // row * columns + column
  const pgm::BeamLayout* layout = nullptr;
};

// Fills `out` (cleared first; osi/sensor_data_proto.cpp, with libprotobuf): clouds[i] is the cloud of scene.detectors[i] (same count). `cycle`
// is the frame counter written into the headers.
void build_sensor_data(const SceneFrame& scene, const std::vector<ReportedDetection>& objects,
                       const std::vector<sensor::LanePolynomial>& lanes, const std::vector<CloudRef>& clouds,
                       const IdMap& ids, std::uint64_t cycle, osi3::SensorData& out);

// The same SensorData as build_sensor_data, encoded straight into its wire bytes (osi/wire.h)
// without building ~60 k protobuf objects: byte for byte what build_sensor_data followed by
// SerializeToString gives (tests/osi/test_sensor_data_wire.cpp), in a fraction of the time.
// `out` is resized to `prefix` + the message's size and the message written from out[prefix], so a
// caller can put a length field in front without a copy; its capacity is kept from call to call.
void encode_sensor_data(const SceneFrame& scene, const std::vector<ReportedDetection>& objects,
                        const std::vector<sensor::LanePolynomial>& lanes, const std::vector<CloudRef>& clouds,
                        const IdMap& ids, std::uint64_t cycle, std::string& out, std::size_t prefix = 0);

// Values both writers share.
msg::LaneBoundaryType osi_lane_type(sensor::LaneType t);
std::uint64_t osi_id_of(int model_id, const IdMap& ids);  // kNoObject for ids without an OSI id
std::uint64_t osi_tracking_id(int track_id);              // false positives above kFalsePositiveIdBase
int lane_point_count(const sensor::LanePolynomial& p);    // points every 1 m over the valid range, >= 2
Eigen::Vector2d lane_point(const sensor::LanePolynomial& p, int k, int n);  // (x, y) of point k of n
std::vector<double> column_azimuths(const pgm::BeamLayout& layout);         // per column, in [-pi, pi]

// With libprotobuf (osi/sensor_data_proto.cpp).
void set_version(osi3::InterfaceVersion& v);
// An OSI vector from ours (x, y, z in metres or their derivatives).
void set_vector(const Eigen::Vector3d& p, osi3::Vector3d& v);

}  // namespace lidarsim::osi
