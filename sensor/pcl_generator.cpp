#include "sensor/pcl_generator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "common/angles.h"
#include "common/error.h"
#include "pgm/materials.h"
#include "pgm/projection.h"
#include "sensor/fov.h"
#include "sensor/frames.h"
#include "sensor/range_noise.h"
#include "sensor/return_model.h"

namespace lidarsim::sensor {

PclConfig PclConfig::from_fov(const FieldOfView& fov) {
  PclConfig c;
  c.min_range = fov.range_min;
  c.max_range = fov.range_max;
  c.azimuth_min = fov.azimuth_min;
  c.azimuth_max = fov.azimuth_max;
  c.elevation_min = fov.elevation_min;
  c.elevation_max = fov.elevation_max;
  return c;
}

PclGenerator::PclGenerator(pgm::BeamLayout layout, const Pose& mount, const PclConfig& config)
    : layout_(std::move(layout)), mount_(mount), sensor_from_ego_(inverse(mount)), cfg_(config) {
  layout_.validate("pcl generator");
  if (cfg_.returns && cfg_.returns->rows() != layout_.rows())
    throw Error("pcl generator: the return model has " + std::to_string(cfg_.returns->rows()) + " lasers (" +
                cfg_.returns->layout().name + "), the beam layout " + std::to_string(layout_.rows()) + " rows");
  // A sensor described by data brings its own range limits; the narrower of both wins.
  if (layout_.max_range_m > 0) cfg_.max_range = std::min(cfg_.max_range, layout_.max_range_m);
  cfg_.min_range = std::max(cfg_.min_range, layout_.min_range_m);
  const int H = layout_.rows(), W = layout_.columns;
  dir_sensor_.resize(static_cast<std::size_t>(H) * W);
  dir_ego_.resize(dir_sensor_.size());
  slope_.resize(dir_sensor_.size());
  cell_in_fov_.resize(dir_sensor_.size());
  FieldOfView fov;  // the angular limits only: range is handled while casting
  fov.azimuth_min = cfg_.azimuth_min;
  fov.azimuth_max = cfg_.azimuth_max;
  fov.elevation_min = cfg_.elevation_min;
  fov.elevation_max = cfg_.elevation_max;
  fov.range_min = 0;
  fov.range_max = 2;
  for (int r = 0; r < H; ++r) {
    const double el = layout_.elevations_rad[r];
    for (int c = 0; c < W; ++c) {
      // Beams of one column fire at per-beam azimuth offsets (Ouster's beam_azimuth_angles).
      const double az = layout_.azimuth_of_column(c) + layout_.azimuth_offset(r);
      const std::size_t i = static_cast<std::size_t>(r) * W + c;
      dir_sensor_[i] = Eigen::Vector3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
      dir_ego_[i] = mount_.rotation * dir_sensor_[i];
      slope_[i] = static_cast<float>(dir_ego_[i].z() / std::hypot(dir_ego_[i].x(), dir_ego_[i].y()));
      cell_in_fov_[i] = point_in_fov(dir_sensor_[i], fov);
    }
  }
  col_start_.assign(W + 1, 0);
  col_fill_.assign(W, 0);
  const double reach = cfg_.max_range + cfg_.lane_width;
  grid_n_ = std::max(1, static_cast<int>(std::ceil(2 * reach / grid_cell_)));
  grid_origin_ = -reach;  // relative to the mount's ground point
  cell_start_.assign(static_cast<std::size_t>(grid_n_) * grid_n_ + 1, 0);
  cell_fill_.assign(static_cast<std::size_t>(grid_n_) * grid_n_, 0);
}

pgm::PolarGridMap PclGenerator::make_map(const std::vector<std::string>& extra) const {
  std::vector<std::string> names = kPclChannels;
  for (const auto& e : extra)
    if (std::find(names.begin(), names.end(), e) == names.end()) names.push_back(e);
  return pgm::PolarGridMap(layout_, names);
}

void PclGenerator::add_box(const Eigen::Vector3d& position, const Eigen::Vector3d& size, double heading, int id,
                           int class_id, int material_id) {
  const Eigen::Vector3d& o = mount_.translation;
  Box b;
  b.ray.centre = position;
  b.ray.half = 0.5 * size;
  b.ray.cos_h = std::cos(heading);
  b.ray.sin_h = std::sin(heading);
  b.id = id;
  b.class_id = class_id;
  b.material_id = material_id;
  // The mount in box axes: the nearest point of the box (a lower bound of any hit's range) and the
  // nearest and farthest horizontal distance of its footprint.
  const Eigen::Vector3d r = o - position;
  const double lx = b.ray.cos_h * r.x() + b.ray.sin_h * r.y(), ly = -b.ray.sin_h * r.x() + b.ray.cos_h * r.y();
  const double ex = std::max(0.0, std::abs(lx) - b.ray.half.x()), ey = std::max(0.0, std::abs(ly) - b.ray.half.y());
  const double ez = std::max(0.0, std::abs(r.z()) - b.ray.half.z());
  const double near = std::sqrt(ex * ex + ey * ey + ez * ez);
  if (near > cfg_.max_range) return;  // no beam reaches it
  const double s_near = std::hypot(ex, ey);
  const double s_far = std::hypot(std::abs(lx) + b.ray.half.x(), std::abs(ly) + b.ray.half.y());
  // Slopes (dz / horizontal distance) from the mount of the box's highest and lowest points: a
  // ray whose slope is outside cannot meet it. Widened a little against rounding.
  const double zt = position.z() + b.ray.half.z() - o.z(), zb = position.z() - b.ray.half.z() - o.z();
  const double inf = std::numeric_limits<double>::infinity();
  const double hi = zt > 0 ? (s_near > 0 ? zt / s_near : inf) : zt / s_far;
  const double lo = zb < 0 ? (s_near > 0 ? zb / s_near : -inf) : zb / s_far;
  b.near = static_cast<float>(near * (1 - 1e-6));
  b.slope_lo = static_cast<float>(lo - 1e-5 * (1 + std::abs(lo)));
  b.slope_hi = static_cast<float>(hi + 1e-5 * (1 + std::abs(hi)));
  boxes_.push_back(b);
}

void PclGenerator::prepare_boxes(const std::vector<Object>& objects, const std::vector<SceneryBox>& scenery) {
  const int W = layout_.columns;
  const double res = 2 * kPi / W;
  boxes_.clear();
  box_cols_.clear();
  std::fill(col_start_.begin(), col_start_.end(), 0);
  for (const auto& o : objects)
    add_box(o.position, o.size, o.heading, o.id, pgm::class_from_object_type(to_string(o.cls)),
            pgm::material_from_name(o.material));
  for (const auto& s : scenery) add_box(s.position, s.size, s.heading, -1, s.class_id, s.material_id);
  // Nearest first in every column, so that a cast stops at the first box beyond its best hit.
  std::stable_sort(boxes_.begin(), boxes_.end(), [](const Box& a, const Box& b) { return a.near < b.near; });
  Object o;
  Eigen::Vector3d corners[8];
  for (const auto& b : boxes_) {
    // Column span from the corners seen from the sensor (all columns when the sensor's vertical
    // axis may pass through the box, where corners no longer bound the azimuth).
    o.position = b.ray.centre;
    o.size = 2 * b.ray.half;
    o.heading = std::atan2(b.ray.sin_h, b.ray.cos_h);
    box_corners(o, corners);
    const Eigen::Vector3d c_s = apply(sensor_from_ego_, o.position);
    const double half_diag = 0.5 * o.size.norm();
    int first = 0, count = W;
    if (std::hypot(c_s.x(), c_s.y()) > half_diag + 1e-6) {
      const double az_c = std::atan2(c_s.y(), c_s.x());
      double lo = 0, hi = 0;
      for (const auto& p : corners) {
        const Eigen::Vector3d q = apply(sensor_from_ego_, p);
        const double rel = wrap_pi(std::atan2(q.y(), q.x()) - az_c);
        lo = std::min(lo, rel);
        hi = std::max(hi, rel);
      }
      double az_lo = az_c + lo;
      if (az_lo < 0) az_lo += 2 * kPi;
      first = static_cast<int>(std::floor(az_lo / res)) % W;
      count = std::min(W, static_cast<int>(std::ceil((hi - lo) / res)) + 2);
    }
    box_cols_.emplace_back(first, count);
    for (int k = 0; k < count; ++k) ++col_start_[(first + k) % W + 1];
  }
  for (int c = 0; c < W; ++c) col_start_[c + 1] += col_start_[c];
  box_index_.resize(col_start_[W]);
  std::fill(col_fill_.begin(), col_fill_.end(), 0);
  for (int i = 0; i < static_cast<int>(boxes_.size()); ++i) {
    const auto [first, count] = box_cols_[i];
    for (int k = 0; k < count; ++k) {
      const int c = (first + k) % W;
      box_index_[col_start_[c] + col_fill_[c]++] = i;
    }
  }
}

void PclGenerator::prepare_lanes(const std::vector<LanePolyline>& lanes) {
  segments_.clear();
  seg_cells_lo_.clear();
  seg_cells_hi_.clear();
  std::fill(cell_start_.begin(), cell_start_.end(), 0);
  const double half_w = 0.5 * cfg_.lane_width;
  const double ox = mount_.translation.x() + grid_origin_, oy = mount_.translation.y() + grid_origin_;
  auto cell_of = [&](double v, double o) {
    return std::clamp(static_cast<int>(std::floor((v - o) / grid_cell_)), -1, grid_n_);
  };
  for (const auto& lane : lanes) {
    if (lane.type == LaneType::RoadEdge) continue;  // a kerb, not paint
    double s = 0;
    for (std::size_t i = 1; i < lane.points.size(); ++i) {
      const auto& a = lane.points[i - 1];
      const auto& b = lane.points[i];
      const double len = std::hypot(b.x() - a.x(), b.y() - a.y());
      const Segment seg{a.x(), a.y(), b.x(), b.y(), s, lane.type};
      s += len;
      const int x0 = cell_of(std::min(a.x(), b.x()) - half_w, ox), x1 = cell_of(std::max(a.x(), b.x()) + half_w, ox);
      const int y0 = cell_of(std::min(a.y(), b.y()) - half_w, oy), y1 = cell_of(std::max(a.y(), b.y()) + half_w, oy);
      if (x1 < 0 || y1 < 0 || x0 >= grid_n_ || y0 >= grid_n_) continue;  // beyond the sensor's reach
      const std::pair<int, int> lo{std::max(0, x0), std::max(0, y0)}, hi{std::min(grid_n_ - 1, x1), std::min(grid_n_ - 1, y1)};
      for (int gx = lo.first; gx <= hi.first; ++gx)
        for (int gy = lo.second; gy <= hi.second; ++gy) ++cell_start_[static_cast<std::size_t>(gx) * grid_n_ + gy + 1];
      segments_.push_back(seg);
      seg_cells_lo_.push_back(lo);
      seg_cells_hi_.push_back(hi);
    }
  }
  const std::size_t n_cells = static_cast<std::size_t>(grid_n_) * grid_n_;
  for (std::size_t c = 0; c < n_cells; ++c) cell_start_[c + 1] += cell_start_[c];
  seg_index_.resize(cell_start_[n_cells]);
  std::fill(cell_fill_.begin(), cell_fill_.end(), 0);
  for (int i = 0; i < static_cast<int>(segments_.size()); ++i)
    for (int gx = seg_cells_lo_[i].first; gx <= seg_cells_hi_[i].first; ++gx)
      for (int gy = seg_cells_lo_[i].second; gy <= seg_cells_hi_[i].second; ++gy) {
        const std::size_t c = static_cast<std::size_t>(gx) * grid_n_ + gy;
        seg_index_[cell_start_[c] + cell_fill_[c]++] = i;
      }
}

bool PclGenerator::painted(double x, double y) const {
  const int gx = static_cast<int>(std::floor((x - mount_.translation.x() - grid_origin_) / grid_cell_));
  const int gy = static_cast<int>(std::floor((y - mount_.translation.y() - grid_origin_) / grid_cell_));
  if (gx < 0 || gy < 0 || gx >= grid_n_ || gy >= grid_n_) return false;
  const std::size_t c = static_cast<std::size_t>(gx) * grid_n_ + gy;
  const double half_w = 0.5 * cfg_.lane_width, period = cfg_.dash_length + cfg_.dash_gap;
  for (int k = cell_start_[c]; k < cell_start_[c + 1]; ++k) {
    const Segment& s = segments_[seg_index_[k]];
    const double dx = s.bx - s.ax, dy = s.by - s.ay, len2 = dx * dx + dy * dy;
    const double t = len2 > 0 ? std::clamp(((x - s.ax) * dx + (y - s.ay) * dy) / len2, 0.0, 1.0) : 0.0;
    const double ex = s.ax + t * dx - x, ey = s.ay + t * dy - y;
    if (ex * ex + ey * ey > half_w * half_w) continue;
    if (s.type == LaneType::Dashed && std::fmod(s.s0 + t * std::sqrt(len2), period) >= cfg_.dash_length) continue;
    return true;
  }
  return false;
}

namespace {

// What a cast met: a box index (>= 0) or one of these.
constexpr int kNoHit = -1, kRoad = -2, kLanePaint = -3;

// The map's channels the generator writes; the optional ones are null when the map lacks them.
struct Channels {
  float *range, *cls, *material, *intensity, *mask, *id;
  float *el, *az, *height, *x, *y, *z;
  std::vector<std::int64_t>* point_index;
  bool any_geometry() const { return el || az || height || x || y || z; }
};

Channels channels_of(pgm::PolarGridMap& out) {
  auto optional = [&](const char* n) { return out.has_channel(n) ? out.channel(n) : nullptr; };
  return {out.channel("range"), out.channel("class"), out.channel("material"), out.channel("intensity"),
          out.channel("mask"), out.channel("object_id"), optional("elevation"), optional("azimuth"),
          optional("height"), optional("x"), optional("y"), optional("z"), &out.point_index()};
}

void write_no_return(const Channels& ch, std::size_t cell) {
  ch.range[cell] = ch.cls[cell] = ch.material[cell] = ch.intensity[cell] = ch.mask[cell] = 0.f;
  ch.id[cell] = -1.f;
  for (float* f : {ch.el, ch.az, ch.height, ch.x, ch.y, ch.z})
    if (f) f[cell] = 0.f;
  (*ch.point_index)[cell] = -1;
}

// A return of range `range` in cell (r, c) on a surface of these labels.
void write_return(const Channels& ch, const pgm::BeamLayout& layout, const Eigen::Vector3d& dir_sensor, int r, int c,
                  std::size_t cell, double range, int class_id, int material_id, int id) {
  ch.range[cell] = static_cast<float>(range);
  ch.intensity[cell] = 0.f;
  ch.mask[cell] = 1.f;
  ch.cls[cell] = static_cast<float>(class_id);
  ch.material[cell] = static_cast<float>(material_id);
  ch.id[cell] = static_cast<float>(id);
  (*ch.point_index)[cell] = static_cast<std::int64_t>(cell);
  if (!ch.any_geometry()) return;
  const Eigen::Vector3d p = range * dir_sensor;
  if (ch.el) ch.el[cell] = static_cast<float>(layout.elevations_rad[r]);
  if (ch.az) ch.az[cell] = static_cast<float>(layout.azimuth_of_column(c));
  if (ch.height) ch.height[cell] = static_cast<float>(p.z());
  if (ch.x) ch.x[cell] = static_cast<float>(p.x());
  if (ch.y) ch.y[cell] = static_cast<float>(p.y());
  if (ch.z) ch.z[cell] = static_cast<float>(p.z());
}

// Incidence and depth discontinuity, where the map has them: computed from the final ranges, or
// zero when the caller does not need them.
void fill_neighbourhood_channels(pgm::PolarGridMap& out, bool neighbourhood_channels) {
  for (const char* name : {"incidence", "depth_discontinuity"}) {
    if (!out.has_channel(name)) continue;
    if (!neighbourhood_channels) std::fill_n(out.channel(name), out.cells(), 0.f);
    else if (name[0] == 'i') pgm::compute_incidence(out);
    else pgm::compute_depth_discontinuity(out);
  }
}

}  // namespace

PclGenerator::Hit PclGenerator::cast(std::size_t cell, int c, bool lanes_on) const {
  const Eigen::Vector3d& origin = mount_.translation;
  const Eigen::Vector3d& d = dir_ego_[cell];
  Hit h{cfg_.max_range, kNoHit};
  if (!cell_in_fov_[cell]) return h;
  if (cfg_.ground && d.z() < 0) {
    const double t = (cfg_.ground_height - origin.z()) / d.z();
    if (t >= 0 && t < h.range) h = {t, kRoad};
  }
  // Boxes come nearest first: once a box's nearest point is beyond the best hit, so are the rest.
  // A box wins a tie with the road (a box standing on it).
  const float slope = slope_[cell];
  for (int k = col_start_[c]; k < col_start_[c + 1]; ++k) {
    const Box& b = boxes_[box_index_[k]];
    if (b.near > h.range) break;
    if (slope < b.slope_lo || slope > b.slope_hi) continue;
    double t = 0;
    if (ray_box(b.ray, origin, d, h.range, t) && (t < h.range || (t == h.range && h.target == kRoad))) {
      h.range = t;
      h.target = box_index_[k];
    }
  }
  if (h.target == kRoad && lanes_on) {
    const Eigen::Vector3d p = origin + h.range * d;
    if (painted(p.x(), p.y())) h.target = kLanePaint;
  }
  return h;
}

int PclGenerator::generate(const std::vector<Object>& objects_ego, const std::vector<LanePolyline>& lanes_ego,
                           pgm::PolarGridMap& out, bool neighbourhood_channels) {
  static const std::vector<SceneryBox> none;
  return generate(objects_ego, none, lanes_ego, out, neighbourhood_channels);
}

int PclGenerator::generate(const std::vector<Object>& objects_ego, const std::vector<SceneryBox>& scenery_ego,
                           const std::vector<LanePolyline>& lanes_ego, pgm::PolarGridMap& out,
                           bool neighbourhood_channels) {
  if (!(out.layout() == layout_)) throw Error("pcl generator: the map's beam layout differs from the generator's");
  for (const auto& name : kPclChannels)
    if (!out.has_channel(name)) out.add_channel(name);
  prepare_boxes(objects_ego, scenery_ego);
  if (cfg_.lanes) prepare_lanes(lanes_ego);
  else segments_.clear();

  const int H = layout_.rows(), W = layout_.columns;
  const Channels ch = channels_of(out);
  const bool lanes_on = cfg_.lanes && !segments_.empty();
  int returns = 0;

#pragma omp parallel for schedule(dynamic, 4) reduction(+ : returns)
  for (int r = 0; r < H; ++r) {
    for (int c = 0; c < W; ++c) {
      const std::size_t cell = static_cast<std::size_t>(r) * W + c;
      const Hit hit = cast(cell, c, lanes_on);
      if (hit.target == kNoHit || hit.range < cfg_.min_range) {
        write_no_return(ch, cell);
        continue;
      }
      ++returns;
      if (hit.target >= 0) {
        const Box& b = boxes_[hit.target];
        write_return(ch, layout_, dir_sensor_[cell], r, c, cell, hit.range, b.class_id, b.material_id, b.id);
      } else if (hit.target == kLanePaint) {
        write_return(ch, layout_, dir_sensor_[cell], r, c, cell, hit.range, pgm::cls::lane_marking,
                     pgm::material::lane_paint, -1);
      } else {
        write_return(ch, layout_, dir_sensor_[cell], r, c, cell, hit.range, pgm::cls::road, pgm::material::asphalt, -1);
      }
    }
  }
  // The post-passes, in this order: drops of the return model, then noise on the ranges kept.
  if (cfg_.returns) returns -= apply_return_model(*cfg_.returns, out, cfg_.return_seed, frame_);
  if (cfg_.range_noise) apply_range_noise(*cfg_.range_noise, cfg_.range_noise_seed, frame_, out);
  ++frame_;
  fill_neighbourhood_channels(out, neighbourhood_channels);
  return returns;
}

void select_visible(const std::vector<Object>& ego_objects, const std::vector<Object>& visible, std::vector<Object>& out) {
  out.clear();
  for (const auto& o : ego_objects)
    for (const auto& v : visible)
      if (v.id == o.id && v.visible_fraction > 0) {
        out.push_back(o);
        break;
      }
}

}  // namespace lidarsim::sensor
