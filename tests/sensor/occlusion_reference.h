#pragma once
// A plain occlusion raster (one 3-D slab test per cell of a conservative angular rectangle),
// kept as the reference that sensor::Occlusion must agree with. Objects
// only: the visible fractions and per-object cell counts; lanes are checked by their own tests.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include "sensor/fov.h"
#include "sensor/frames.h"
#include "sensor/occlusion.h"

namespace lidarsim::sensor::reference {

class ReferenceOcclusion {
 public:
  explicit ReferenceOcclusion(const OcclusionConfig& config = {}) : cfg_(config) {
    constexpr double pi = std::numbers::pi;
    cols_ = std::max(1, static_cast<int>(std::lround(2 * pi / cfg_.azimuth_resolution)));
    cfg_.azimuth_resolution = 2 * pi / cols_;
    rows_ = std::max(1, static_cast<int>(std::ceil((cfg_.elevation_max - cfg_.elevation_min) / cfg_.elevation_resolution)));
    for (int c = 0; c < cols_; ++c) {
      az_cos_.push_back(std::cos((c + 0.5) * cfg_.azimuth_resolution));
      az_sin_.push_back(std::sin((c + 0.5) * cfg_.azimuth_resolution));
    }
    for (int r = 0; r < rows_; ++r) {
      const double el = cfg_.elevation_max - (r + 0.5) * cfg_.elevation_resolution;
      el_cos_.push_back(std::cos(el));
      el_sin_.push_back(std::sin(el));
    }
    depth_.assign(static_cast<std::size_t>(rows_) * cols_, std::numeric_limits<float>::infinity());
    owner_.assign(depth_.size(), -1);
  }

  void apply(std::vector<Object>& objects) {
    for (int cell : touched_) {  // as it was: only the cells the previous frame wrote
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
      int r = 0, c = 0;
      const double near = closest_point_on_box(obj, Eigen::Vector3d::Zero()).norm();
      obj.visible_fraction = (!cell_of(obj.position, r, c) || depth_[static_cast<std::size_t>(r) * cols_ + c] >= near) ? 1 : 0;
    }
  }
  const std::vector<int>& footprint_cells() const { return footprint_; }
  const std::vector<int>& visible_cells() const { return visible_; }

 private:
  bool cell_of(const Eigen::Vector3d& p, int& row, int& col) const {
    double az = std::atan2(p.y(), p.x());
    if (az < 0) az += 2 * std::numbers::pi;
    col = std::min(cols_ - 1, static_cast<int>(az / cfg_.azimuth_resolution));
    const double el = std::atan2(p.z(), std::hypot(p.x(), p.y()));
    const double rr = (cfg_.elevation_max - el) / cfg_.elevation_resolution;
    if (rr < 0 || rr >= rows_) return false;
    row = static_cast<int>(rr);
    return true;
  }

  void rasterise(const Object& o, int index) {
    constexpr double pi = std::numbers::pi;
    const RayBox box = RayBox::of(o);
    Eigen::Vector3d corners[8];
    box_corners(o, corners);
    const Eigen::Vector3d below = closest_point_on_box(o, Eigen::Vector3d(0, 0, o.position.z()));
    const double dist_xy = std::hypot(below.x(), below.y());
    const double az_c = std::atan2(o.position.y(), o.position.x());
    double a_lo = 0, a_hi = 0;
    if (dist_xy < 1e-9) {
      a_lo = -pi;
      a_hi = pi;
    } else {
      for (const auto& p : corners) {
        const double rel = wrap_pi(std::atan2(p.y(), p.x()) - az_c);
        a_lo = std::min(a_lo, rel);
        a_hi = std::max(a_hi, rel);
      }
    }
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
    if (az_lo < 0) az_lo += 2 * pi;
    const int c0 = static_cast<int>(std::floor(az_lo / res_a));
    const int n_cols = std::min(cols_, static_cast<int>(std::ceil((a_hi - a_lo) / res_a)) + 2);
    int footprint = 0;
    for (int k = 0; k < n_cols; ++k) {
      const int c = ((c0 + k) % cols_ + cols_) % cols_;
      for (int r = r0; r <= r1; ++r) {
        const Eigen::Vector3d d(el_cos_[r] * az_cos_[c], el_cos_[r] * az_sin_[c], el_sin_[r]);
        double t = 0;
        if (!ray_box(box, Eigen::Vector3d::Zero(), d, std::numeric_limits<double>::infinity(), t)) continue;
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

  OcclusionConfig cfg_;
  int rows_ = 0, cols_ = 0;
  std::vector<double> az_cos_, az_sin_, el_cos_, el_sin_;
  std::vector<float> depth_;
  std::vector<int> owner_, touched_, footprint_, visible_;
};

}  // namespace lidarsim::sensor::reference
