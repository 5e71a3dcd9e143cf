// The values both SensorData writers share (osi/sensor_data.h); no Protocol Buffers here.
#include "osi/sensor_data.h"

#include <algorithm>
#include <cmath>

#include "sensor/frames.h"

namespace lidarsim::osi {

msg::LaneBoundaryType osi_lane_type(sensor::LaneType t) {
  switch (t) {
    case sensor::LaneType::Dashed: return msg::kDashedLine;
    case sensor::LaneType::RoadEdge: return msg::kRoadEdge;
    default: return msg::kSolidLine;
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

}  // namespace lidarsim::osi
