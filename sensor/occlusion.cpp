#include "sensor/occlusion.h"
#include "sensor/frames.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace lidarsim::sensor {

namespace {
constexpr double kPi = std::numbers::pi;
}  // namespace

RayBox RayBox::of(const Object& o) {
  RayBox b;
  b.centre = o.position;
  b.half = 0.5 * o.size;
  b.cos_h = std::cos(o.heading);
  b.sin_h = std::sin(o.heading);
  return b;
}

bool ray_box(const RayBox& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_max, double& t_hit,
             int* normal_axis, int* normal_sign) {
  // Into box coordinates (rotate by -heading about z).
  const Eigen::Vector3d r = o - b.centre;
  const double lo[3] = {b.cos_h * r.x() + b.sin_h * r.y(), -b.sin_h * r.x() + b.cos_h * r.y(), r.z()};
  const double ld[3] = {b.cos_h * d.x() + b.sin_h * d.y(), -b.sin_h * d.x() + b.cos_h * d.y(), d.z()};
  double t0 = 0, t1 = t_max;
  int axis = -1, sign = 0;
  for (int i = 0; i < 3; ++i) {
    const double h = b.half[i];
    if (std::abs(ld[i]) < 1e-15) {
      if (lo[i] < -h || lo[i] > h) return false;
      continue;
    }
    const double inv = 1.0 / ld[i];
    double ta = (-h - lo[i]) * inv, tb = (h - lo[i]) * inv;
    int s = -1;  // entering through the -h face when ta < tb
    if (ta > tb) {
      std::swap(ta, tb);
      s = 1;
    }
    if (ta > t0) {
      t0 = ta;
      axis = i;
      sign = s;
    }
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  t_hit = t0;
  if (normal_axis) *normal_axis = axis;  // -1: origin inside the box
  if (normal_sign) *normal_sign = sign;
  return true;
}

OcclusionConfig OcclusionConfig::for_fov(const FieldOfView& fov, double resolution_rad) {
  OcclusionConfig c;
  c.azimuth_resolution = c.elevation_resolution = resolution_rad;
  c.elevation_min = std::max(fov.elevation_min, -kPi / 2 + 1e-6);
  c.elevation_max = std::min(fov.elevation_max, kPi / 2 - 1e-6);
  return c;
}

Occlusion::Occlusion(const OcclusionConfig& config) : cfg_(config) {
  cols_ = std::max(1, static_cast<int>(std::lround(2 * kPi / cfg_.azimuth_resolution)));
  cfg_.azimuth_resolution = 2 * kPi / cols_;
  rows_ = std::max(1, static_cast<int>(std::ceil((cfg_.elevation_max - cfg_.elevation_min) / cfg_.elevation_resolution)));
  az_cos_.resize(cols_);
  az_sin_.resize(cols_);
  for (int c = 0; c < cols_; ++c) {  // column c covers azimuth [c, c+1) * res, az in [0, 2pi)
    const double az = (c + 0.5) * cfg_.azimuth_resolution;
    az_cos_[c] = std::cos(az);
    az_sin_[c] = std::sin(az);
  }
  el_cos_.resize(rows_);
  el_sin_.resize(rows_);
  for (int r = 0; r < rows_; ++r) {  // row 0 at the top
    const double el = cfg_.elevation_max - (r + 0.5) * cfg_.elevation_resolution;
    el_cos_[r] = std::cos(el);
    el_sin_[r] = std::sin(el);
  }
  depth_.assign(static_cast<std::size_t>(rows_) * cols_, std::numeric_limits<float>::infinity());
  owner_.assign(depth_.size(), -1);
}

bool Occlusion::cell_of(const Eigen::Vector3d& p, int& row, int& col) const {
  double az = std::atan2(p.y(), p.x());
  if (az < 0) az += 2 * kPi;
  col = std::min(cols_ - 1, static_cast<int>(az / cfg_.azimuth_resolution));
  const double el = std::atan2(p.z(), std::hypot(p.x(), p.y()));
  const double rr = (cfg_.elevation_max - el) / cfg_.elevation_resolution;
  if (rr < 0 || rr >= rows_) return false;
  row = static_cast<int>(rr);
  return true;
}

void Occlusion::rasterise(const Object& o, int index) {
  const RayBox box = RayBox::of(o);
  Eigen::Vector3d corners[8];
  box_corners(o, corners);
  // Azimuth span from the vertical edges, relative to the centre's azimuth (one interval
  // across the seam); the full circle when the sensor is above/below the box's footprint.
  const Eigen::Vector3d below = closest_point_on_box(o, Eigen::Vector3d(0, 0, o.position.z()));
  const double dist_xy = std::hypot(below.x(), below.y());
  const double az_c = std::atan2(o.position.y(), o.position.x());
  double a_lo = 0, a_hi = 0;
  if (dist_xy < 1e-9) {
    a_lo = -kPi;
    a_hi = kPi;
  } else {
    for (const auto& p : corners) {
      const double rel = wrap_pi(std::atan2(p.y(), p.x()) - az_c);
      a_lo = std::min(a_lo, rel);
      a_hi = std::max(a_hi, rel);
    }
  }
  // Elevation span: corners, plus top and bottom at the horizontally nearest point.
  const double z_top = o.position.z() + 0.5 * o.size.z(), z_bot = o.position.z() - 0.5 * o.size.z();
  double e_lo = std::atan2(z_bot, std::max(dist_xy, 1e-9)), e_hi = std::atan2(z_top, std::max(dist_xy, 1e-9));
  for (const auto& p : corners) {
    const double el = std::atan2(p.z(), std::hypot(p.x(), p.y()));
    e_lo = std::min(e_lo, el);
    e_hi = std::max(e_hi, el);
  }
  const double res_a = cfg_.azimuth_resolution, res_e = cfg_.elevation_resolution;
  const int r0 = std::max(0, static_cast<int>(std::floor((cfg_.elevation_max - e_hi) / res_e)));
  const int r1 = std::min(rows_ - 1, static_cast<int>(std::floor((cfg_.elevation_max - e_lo) / res_e)));
  double az_lo = az_c + a_lo;
  if (az_lo < 0) az_lo += 2 * kPi;
  const int c0 = static_cast<int>(std::floor(az_lo / res_a));
  const int n_cols = std::min(cols_, static_cast<int>(std::ceil((a_hi - a_lo) / res_a)) + 2);

  const Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  int footprint = 0;
  for (int k = 0; k < n_cols; ++k) {
    const int c = ((c0 + k) % cols_ + cols_) % cols_;
    for (int r = r0; r <= r1; ++r) {
      const Eigen::Vector3d d(el_cos_[r] * az_cos_[c], el_cos_[r] * az_sin_[c], el_sin_[r]);
      double t = 0;
      if (!ray_box(box, origin, d, std::numeric_limits<double>::infinity(), t)) continue;
      ++footprint;
      const std::size_t cell = static_cast<std::size_t>(r) * cols_ + c;
      if (owner_[cell] < 0) touched_.push_back(static_cast<int>(cell));
      if (t < depth_[cell]) {
        depth_[cell] = static_cast<float>(t);
        owner_[cell] = index;
      }
    }
  }
  footprint_[index] = footprint;
}

void Occlusion::apply(std::vector<Object>& objects, std::vector<LanePolyline>& lanes) {
  // Reset only the cells the previous frame wrote (a full clear costs more than a frame of boxes).
  for (int cell : touched_) {
    depth_[cell] = std::numeric_limits<float>::infinity();
    owner_[cell] = -1;
  }
  touched_.clear();
  const int n = static_cast<int>(objects.size());
  footprint_.assign(n, 0);
  visible_.assign(n, 0);
  for (int i = 0; i < n; ++i) rasterise(objects[i], i);
  for (int cell : touched_) ++visible_[owner_[cell]];
  for (int i = 0; i < n; ++i) {
    Object& obj = objects[i];
    if (footprint_[i] > 0) {
      obj.visible_fraction = static_cast<double>(visible_[i]) / footprint_[i];
      continue;
    }
    // Smaller than a cell: visible when nothing nearer covers its centre direction.
    int r = 0, c = 0;
    const double near = closest_point_on_box(obj, Eigen::Vector3d::Zero()).norm();
    obj.visible_fraction = (!cell_of(obj.position, r, c) || depth_[static_cast<std::size_t>(r) * cols_ + c] >= near) ? 1 : 0;
  }
  for (auto& lane : lanes) {
    std::erase_if(lane.points, [&](const Eigen::Vector3d& p) {
      int r = 0, c = 0;
      if (!cell_of(p, r, c)) return false;
      const std::size_t cell = static_cast<std::size_t>(r) * cols_ + c;
      return owner_[cell] >= 0 && p.norm() > depth_[cell];
    });
  }
  std::erase_if(lanes, [](const LanePolyline& l) { return l.points.size() < 2; });
}

}  // namespace lidarsim::sensor
