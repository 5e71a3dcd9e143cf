#include "sensor/fov.h"
#include "sensor/frames.h"

#include <algorithm>
#include <limits>

namespace lidarsim::sensor {

namespace {

constexpr double kPi = std::numbers::pi;


bool full_circle(const FieldOfView& fov) { return fov.azimuth_max - fov.azimuth_min >= 2 * kPi - 1e-12; }

// Lowest and highest elevation atan2(z, hypot(x, y)) over points: atan2 is monotone in
// z / hypot(x, y), so the extremes are found on that ratio and only they pay for atan2.
void elevation_extremes(const Eigen::Vector3d* pts, int n, double& el_lo, double& el_hi) {
  int i_lo = 0, i_hi = 0;
  double k_lo = std::numeric_limits<double>::infinity(), k_hi = -k_lo;
  for (int i = 0; i < n; ++i) {
    const double k = pts[i].z() / std::sqrt(pts[i].x() * pts[i].x() + pts[i].y() * pts[i].y());
    if (k < k_lo) k_lo = k, i_lo = i;
    if (k > k_hi) k_hi = k, i_hi = i;
  }
  el_lo = std::atan2(pts[i_lo].z(), std::hypot(pts[i_lo].x(), pts[i_lo].y()));
  el_hi = std::atan2(pts[i_hi].z(), std::hypot(pts[i_hi].x(), pts[i_hi].y()));
}

}  // namespace

void box_corners(const Object& o, Eigen::Vector3d corners[8]) {
  const double c = std::cos(o.heading), s = std::sin(o.heading);
  const Eigen::Vector3d half = 0.5 * o.size;
  int k = 0;
  for (int ix = -1; ix <= 1; ix += 2)
    for (int iy = -1; iy <= 1; iy += 2)
      for (int iz = -1; iz <= 1; iz += 2) {
        const double lx = ix * half.x(), ly = iy * half.y();
        corners[k++] = o.position + Eigen::Vector3d(c * lx - s * ly, s * lx + c * ly, iz * half.z());
      }
}

Eigen::Vector3d closest_point_on_box(const Object& o, const Eigen::Vector3d& p) {
  const double c = std::cos(o.heading), s = std::sin(o.heading);
  const Eigen::Vector3d d = p - o.position;
  Eigen::Vector3d local(c * d.x() + s * d.y(), -s * d.x() + c * d.y(), d.z());
  const Eigen::Vector3d half = 0.5 * o.size;
  local = local.cwiseMax(-half).cwiseMin(half);
  return o.position + Eigen::Vector3d(c * local.x() - s * local.y(), s * local.x() + c * local.y(), local.z());
}

bool point_in_fov(const Eigen::Vector3d& p, const FieldOfView& fov) {
  const double r = p.norm();
  if (r < fov.range_min || r > fov.range_max) return false;
  const double el = std::atan2(p.z(), std::hypot(p.x(), p.y()));
  if (el < fov.elevation_min || el > fov.elevation_max) return false;
  if (full_circle(fov)) return true;
  const double az = std::atan2(p.y(), p.x());
  // Limits may be given beyond +-pi (e.g. [90, 270] deg): compare on the circle.
  const double width = fov.azimuth_max - fov.azimuth_min;
  const double rel = wrap_pi(az - fov.azimuth_min);
  return (rel >= 0 ? rel : rel + 2 * kPi) <= width;
}

bool object_in_fov(const Object& o, const FieldOfView& fov) {
  const Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  const Eigen::Vector3d nearest = closest_point_on_box(o, origin);
  const double r_near = nearest.norm();
  if (r_near > fov.range_max) return false;
  Eigen::Vector3d pts[10];
  box_corners(o, pts);
  pts[8] = o.position;
  pts[9] = nearest;
  double r_far = 0;
  for (const auto& p : pts) r_far = std::max(r_far, p.norm());
  if (r_far < fov.range_min) return false;
  if (r_near == 0) return true;  // the sensor is inside the box: every direction sees it

  // Elevation interval first (a full-circle field of view needs no azimuths).
  double el_lo = 0, el_hi = 0;
  elevation_extremes(pts, 10, el_lo, el_hi);
  if (el_hi < fov.elevation_min || el_lo > fov.elevation_max) return false;
  if (full_circle(fov)) return true;
  // Angular interval of the sample points, azimuths taken relative to the centre direction so
  // that a box across the +-pi seam stays one interval.
  const double az_ref = std::atan2(nearest.y(), nearest.x());
  double az_lo = 1e9, az_hi = -1e9;
  for (const auto& p : pts) {
    const double rel = wrap_pi(std::atan2(p.y(), p.x()) - az_ref);
    az_lo = std::min(az_lo, rel);
    az_hi = std::max(az_hi, rel);
  }
  // Sensor straight above or below the box: it spans every azimuth.
  const Eigen::Vector3d below = closest_point_on_box(o, Eigen::Vector3d(0, 0, o.position.z()));
  if (std::hypot(below.x(), below.y()) == 0) return true;
  // The FoV interval relative to the same reference, tested on the circle (three windings).
  const double f_lo = wrap_pi(fov.azimuth_min - az_ref);
  const double width = fov.azimuth_max - fov.azimuth_min;
  for (int k = -1; k <= 1; ++k) {
    const double lo = f_lo + 2 * kPi * k, hi = lo + width;
    if (az_hi >= lo && az_lo <= hi) return true;
  }
  return false;
}

double fov_truncation(const Object& o, const FieldOfView& fov) {
  Eigen::Vector3d corners[8];
  box_corners(o, corners);
  double el_lo = kPi, el_hi = -kPi;
  elevation_extremes(corners, 8, el_lo, el_hi);
  const double width = std::min(fov.azimuth_max - fov.azimuth_min, 2 * kPi);
  double az_span = 0, az_in = 0;
  const Eigen::Vector3d below = closest_point_on_box(o, Eigen::Vector3d(0, 0, o.position.z()));
  if (std::hypot(below.x(), below.y()) == 0) {
    // The sensor's vertical axis passes through the box: every azimuth, and straight down / up.
    az_span = 2 * kPi;
    az_in = width;
    if (o.position.z() - 0.5 * o.size.z() < 0) el_lo = -kPi / 2;
    if (o.position.z() + 0.5 * o.size.z() > 0) el_hi = kPi / 2;
  } else {
    // Azimuths relative to the centre direction, so that a box across the +-pi seam stays one
    // interval (as object_in_fov); the FoV interval tested on the circle (three windings).
    if (full_circle(fov)) {
      az_span = az_in = 1;  // the whole azimuth extent is inside, whatever it is
    } else {
      const double az_ref = std::atan2(o.position.y(), o.position.x());
      double lo = 1e9, hi = -1e9;
      for (const auto& p : corners) {
        const double rel = wrap_pi(std::atan2(p.y(), p.x()) - az_ref);
        lo = std::min(lo, rel);
        hi = std::max(hi, rel);
      }
      az_span = hi - lo;
      const double f_lo = wrap_pi(fov.azimuth_min - az_ref);
      for (int k = -1; k <= 1; ++k) {
        const double a = f_lo + 2 * kPi * k, b = a + width;
        az_in += std::max(0.0, std::min(hi, b) - std::max(lo, a));
      }
    }
  }
  const double el_in = std::max(0.0, std::min(el_hi, fov.elevation_max) - std::max(el_lo, fov.elevation_min));
  const double el_span = el_hi - el_lo;
  // A degenerate extent (a box of zero size along that angle) is in or out as a whole.
  auto azimuth_inside = [&](double az) {
    if (width >= 2 * kPi - 1e-12) return true;
    const double rel = wrap_pi(az - fov.azimuth_min);
    return (rel >= 0 ? rel : rel + 2 * kPi) <= width;
  };
  const double az_share =
      az_span > 0 ? az_in / az_span : azimuth_inside(std::atan2(o.position.y(), o.position.x())) ? 1.0 : 0.0;
  const double el_share =
      el_span > 0 ? el_in / el_span : el_lo >= fov.elevation_min && el_hi <= fov.elevation_max ? 1.0 : 0.0;
  return std::clamp(1 - std::min(1.0, az_share) * std::min(1.0, el_share), 0.0, 1.0);
}

int apply_fov(std::vector<Object>& objects, const FieldOfView& fov) {
  const auto before = objects.size();
  std::erase_if(objects, [&](const Object& o) { return !object_in_fov(o, fov); });
  for (auto& o : objects) o.truncation = fov_truncation(o, fov);
  return static_cast<int>(before - objects.size());
}

void apply_fov_to_lanes(std::vector<LanePolyline>& lanes, const FieldOfView& fov) {
  for (auto& lane : lanes)
    std::erase_if(lane.points, [&](const Eigen::Vector3d& p) { return !point_in_fov(p, fov); });
  std::erase_if(lanes, [](const LanePolyline& l) { return l.points.size() < 2; });
}

}  // namespace lidarsim::sensor
