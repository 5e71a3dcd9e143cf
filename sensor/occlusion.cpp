#include "sensor/occlusion.h"
#include "sensor/angle_bounds.h"
#include "sensor/frames.h"

#include <algorithm>
#include <utility>
#include <cmath>
#include <limits>
#include <numbers>

#include "nn/cpu_features.h"

#if LIDARSIM_AVX512_KERNELS
#include <immintrin.h>

#include "nn/isa_avx512_begin.h"
namespace lidarsim::sensor::avx512 {
namespace {
// raster_span (below) 16 cells at a time, the last vector masked: the same cells, depths, owners
// and counts as the scalar loop. Returns n; footprint gains the footprint cells.
int raster_span_wide(const float* s_in, const float* s_out, int n, float inv_ce, float t_lo, float t_hi, float* depth,
                     int* owner, int index, int* visible, bool& wrote, int& footprint) {
  const __m512 v_ice = _mm512_set1_ps(inv_ce), v_lo = _mm512_set1_ps(t_lo), v_hi = _mm512_set1_ps(t_hi);
  const __m512i v_index = _mm512_set1_epi32(index);
  int i = 0;
  for (; i < n; i += 16) {
    const __mmask16 live = n - i >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (n - i)) - 1);
    const __m512 t0 = _mm512_max_ps(v_lo, _mm512_mul_ps(_mm512_maskz_loadu_ps(live, s_in + i), v_ice));
    const __m512 t1 = _mm512_min_ps(v_hi, _mm512_mul_ps(_mm512_maskz_loadu_ps(live, s_out + i), v_ice));
    const __mmask16 hit = _mm512_mask_cmp_ps_mask(live, t0, t1, _CMP_LE_OQ);
    if (!hit) continue;
    footprint += __builtin_popcount(hit);
    const __mmask16 win = _mm512_mask_cmp_ps_mask(hit, t0, _mm512_maskz_loadu_ps(hit, depth + i), _CMP_LT_OQ);
    if (!win) continue;
    const __m512i prev = _mm512_maskz_loadu_epi32(win, owner + i);
    unsigned taken = _mm512_mask_cmpge_epi32_mask(win, prev, _mm512_setzero_si512());
    while (taken) {  // rare when boxes come front to back: cells taken from a farther box
      const int j = __builtin_ctz(taken);
      --visible[owner[i + j]];
      taken &= taken - 1;
    }
    visible[index] += __builtin_popcount(win);
    _mm512_mask_storeu_ps(depth + i, win, t0);
    _mm512_mask_storeu_epi32(owner + i, win, v_index);
    wrote = true;
  }
  return n;
}
}  // namespace
}  // namespace lidarsim::sensor::avx512
#include "common/angles.h"
#include "nn/isa_avx512_end.h"
#else
namespace lidarsim::sensor::avx512 {
inline int raster_span_wide(const float*, const float*, int, float, float, float, float*, int*, int, int*, bool&, int&) {
  return 0;
}
}  // namespace lidarsim::sensor::avx512
#endif

namespace lidarsim::sensor {

namespace {
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

Occlusion::Occlusion(const OcclusionConfig& config) : cfg_(config), wide_(nn::isa_at_least(nn::Isa::avx512)) {
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
  az_cos_f_.resize(2 * cols_);
  az_sin_f_.resize(2 * cols_);
  for (int c = 0; c < 2 * cols_; ++c) {
    az_cos_f_[c] = static_cast<float>(az_cos_[c % cols_]);
    az_sin_f_[c] = static_cast<float>(az_sin_[c % cols_]);
  }
  el_cos_.resize(rows_);
  el_sin_.resize(rows_);
  el_inv_cos_.resize(rows_);
  for (int r = 0; r < rows_; ++r) {  // row 0 at the top
    const double el = cfg_.elevation_max - (r + 0.5) * cfg_.elevation_resolution;
    el_cos_[r] = std::cos(el);
    el_sin_[r] = std::sin(el);
    el_inv_cos_[r] = 1 / el_cos_[r];
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

namespace {

// One row's run of candidate cells of box `index`: t_in / t_out per column are the box's 2-D slab
// interval (horizontal distance), scaled by the row's 1 / cos(elevation) into distance along the
// ray and cut by the row's height slab [t_lo, t_hi]. A cell is in the footprint when the interval
// is not empty and the box wins it when it enters nearer than the cell's depth. Returns the
// footprint cells; `visible` gains the wins and loses what this box takes from others.
int raster_span(const float* s_in, const float* s_out, int n, float inv_ce, float t_lo, float t_hi, float* depth,
                int* owner, int index, int* visible, bool& wrote, bool wide) {
  int footprint = 0;
  int i = 0;
  if (wide) i = avx512::raster_span_wide(s_in, s_out, n, inv_ce, t_lo, t_hi, depth, owner, index, visible, wrote,
                                         footprint);
  for (; i < n; ++i) {
    const float t0 = std::max(t_lo, s_in[i] * inv_ce), t1 = std::min(t_hi, s_out[i] * inv_ce);
    if (!(t0 <= t1)) continue;
    ++footprint;
    if (!(t0 < depth[i])) continue;
    if (owner[i] >= 0) --visible[owner[i]];
    ++visible[index];
    depth[i] = t0;
    owner[i] = index;
    wrote = true;
  }
  return footprint;
}

// The angles in rasterise only bound the columns and rows to visit (the slab tests decide every
// cell), so they come from angle_bounds.h, widened by kBoundMargin (5 x their error).
constexpr double kBoundMargin = 5 * kAtanBoundError;

// The columns a box can cover, [first, first + n) modulo cols: the footprint rectangle's bounding
// circle (radius, centre at horizontal distance d_c) bounds its azimuth span, or the full circle
// when the sensor is within it; the per-column slab test then trims the span exactly.
inline void column_window(double cx, double cy, double radius, double d_c, int cols, double res, int& first,
                          int& n) {
  first = 0, n = cols;
  if (d_c > radius * (1 + 1e-9) + 1e-9) {
    double az_c = atan2_bound(cy, cx);
    if (az_c < 0) az_c += 2 * kPi;
    const double half = asin_bound(radius / d_c) + kBoundMargin;
    first = static_cast<int>(std::floor((az_c - half) / res)) - 1;
    n = std::min(cols, static_cast<int>(std::ceil(2 * half / res)) + 3);
  }
  first = ((first % cols) + cols) % cols;
}

// Per column k < n (directions ac[k], as[k]): the 2-D slab interval [in, out] of horizontal
// distance through the rectangle [ax0, ax1] x [ay0, ay1] (box frame, relative to the sensor) of a
// box with heading (fch, fsh). Branch-free: a direction along a slab gets a huge finite inverse,
// so its interval is everything or nothing, as ray_box's parallel case.
inline void column_slabs(const float* ac, const float* as, int n, float fch, float fsh, float ax0, float ax1,
                         float ay0, float ay1, float* in, float* out) {
  for (int k = 0; k < n; ++k) {
    float dx = fch * ac[k] + fsh * as[k], dy = -fsh * ac[k] + fch * as[k];
    dx = std::abs(dx) < 1e-20f ? 1e-20f : dx;
    dy = std::abs(dy) < 1e-20f ? 1e-20f : dy;
    const float ix = 1.f / dx, iy = 1.f / dy;
    const float xa = ax0 * ix, xb = ax1 * ix, ya = ay0 * iy, yb = ay1 * iy;
    in[k] = std::max(0.f, std::max(std::min(xa, xb), std::min(ya, yb)));
    out[k] = std::min(std::max(xa, xb), std::max(ya, yb));
  }
}

// The columns whose slab interval is not empty: the first and last (k_hi < 0: none) and the
// nearest entry and farthest exit over them; then over the whole run [k_lo, k_hi] (empty columns
// included) the least entry and the greatest exit, for the per-row test.
struct ColumnRun {
  int k_lo, k_hi;
  float s_min, s_max, run_in_min, run_out_max;
};
inline ColumnRun column_run(const float* in, const float* out, int n) {
  ColumnRun u{n, -1, std::numeric_limits<float>::infinity(), 0, std::numeric_limits<float>::infinity(), 0};
  for (int k = 0; k < n; ++k) {
    if (!(in[k] <= out[k])) continue;
    u.k_lo = std::min(u.k_lo, k);
    u.k_hi = k;
    u.s_min = std::min(u.s_min, in[k]);
    u.s_max = std::max(u.s_max, out[k]);
  }
  u.run_out_max = -u.run_in_min;
  for (int k = u.k_lo; k <= u.k_hi; ++k) {
    u.run_in_min = std::min(u.run_in_min, in[k]);
    u.run_out_max = std::max(u.run_out_max, out[k]);
  }
  return u;
}

// The height slab [t_lo, t_hi] (distance along the unit ray) of a row with sin(elevation) se
// through heights [z_bot, z_top]; false when the row misses them.
inline bool height_slab(double se, double z_bot, double z_top, double& t_lo, double& t_hi) {
  t_lo = 0, t_hi = std::numeric_limits<double>::infinity();
  if (std::abs(se) < 1e-15) {
    if (z_bot > 0 || z_top < 0) return false;
  } else {
    double ta = z_bot / se, tb = z_top / se;
    if (ta > tb) std::swap(ta, tb);
    t_lo = std::max(t_lo, ta);
    t_hi = tb;
  }
  return !(t_hi < t_lo);
}

}  // namespace

void Occlusion::rasterise(const Eigen::Vector3d& position, const Eigen::Vector3d& size, int index, HeadingTrig h,
                          double d_c) {
  // The box is a vertical prism, so a ray at azimuth a and elevation e runs through it while its
  // horizontal distance s = t cos e is inside the footprint rectangle's 2-D slab interval
  // [s_in(a), s_out(a)] and its height t sin e is inside [z_bot, z_top]. The 2-D interval is
  // worked out once per column, the height slab once per row: a cell then costs two products
  // and a depth test (the same slab test as ray_box, split by axis), 16 cells at a time.
  const double cx = position.x(), cy = position.y();
  const double hx = 0.5 * size.x(), hy = 0.5 * size.y();
  const double ch = h.c, sh = h.s;
  const double lox = -(ch * cx + sh * cy), loy = -(-sh * cx + ch * cy);  // sensor origin in box coordinates
  const double z_top = position.z() + 0.5 * size.z(), z_bot = position.z() - 0.5 * size.z();

  const double radius = std::sqrt(hx * hx + hy * hy);  // d_c = hypot(cx, cy), from apply()
  int c_first = 0, n_cols = cols_;
  column_window(cx, cy, radius, d_c, cols_, cfg_.azimuth_resolution, c_first, n_cols);
  col_in_.resize(n_cols + 16);
  col_out_.resize(n_cols + 16);
  // The direction tables run over two turns: no wrap here.
  column_slabs(az_cos_f_.data() + c_first, az_sin_f_.data() + c_first, n_cols, static_cast<float>(ch),
               static_cast<float>(sh), static_cast<float>(-hx - lox), static_cast<float>(hx - lox),
               static_cast<float>(-hy - loy), static_cast<float>(hy - loy), col_in_.data(), col_out_.data());
  const ColumnRun run = column_run(col_in_.data(), col_out_.data(), n_cols);
  footprint_[index] = 0;
  if (run.k_hi < 0) return;

  // Rows: elevations between the lowest and highest a point of the box can be seen at (heights
  // over the nearest and farthest horizontal distance), one row of margin each side.
  const double s_near = std::max<double>(run.s_min, 1e-9), s_far = std::max<double>(run.s_max, 1e-9);
  const double tan_hi = z_top > 0 ? z_top / s_near : z_top / s_far;
  const double tan_lo = z_bot < 0 ? z_bot / s_near : z_bot / s_far;
  const double res_e = cfg_.elevation_resolution;
  const int r0 = std::max(
      0, static_cast<int>(std::floor((cfg_.elevation_max - (atan_bound(tan_hi) + kBoundMargin)) / res_e)) - 1);
  const int r1 = std::min(
      rows_ - 1, static_cast<int>(std::floor((cfg_.elevation_max - (atan_bound(tan_lo) - kBoundMargin)) / res_e)) + 1);

  // The run of columns may cross the azimuth seam: two pieces then.
  const int k_lo = run.k_lo, c_lo = c_first + k_lo, n_run = run.k_hi - k_lo + 1;
  const int first_piece = std::min(n_run, cols_ - (c_lo % cols_));
  int footprint = 0;
  for (int r = r0; r <= r1; ++r) {
    double t_lo, t_hi;
    if (!height_slab(el_sin_[r], z_bot, z_top, t_lo, t_hi)) continue;
    const float ice = static_cast<float>(el_inv_cos_[r]), flo = static_cast<float>(t_lo),
                fhi = static_cast<float>(std::min(t_hi, 1e30));
    // A row can have a footprint cell only if its height slab [t_lo, t_hi] meets [min s_in, max
    // s_out] / cos(e) over the run: float products are monotone, so a row failing this test fails
    // raster_span's test in every cell, and skipping it changes nothing (it saves the rows of
    // margin and those the bounds above over-estimate).
    if (flo > run.run_out_max * ice || run.run_in_min * ice > fhi) continue;
    const std::size_t row = static_cast<std::size_t>(r) * cols_;
    int done = 0;
    for (int piece = 0; piece < 2 && done < n_run; ++piece) {
      const int len = piece == 0 ? first_piece : n_run - first_piece;
      const int c = (c_lo + done) % cols_;
      bool wrote = false;
      footprint += raster_span(col_in_.data() + k_lo + done, col_out_.data() + k_lo + done, len, ice, flo, fhi,
                               depth_.data() + row + c, owner_.data() + row + c, index, visible_.data(), wrote,
                               wide_);
      if (wrote) written_.push_back({static_cast<int>(row) + c, len});
      done += len;
    }
  }
  footprint_[index] = footprint;
}

void Occlusion::apply(std::vector<Object>& objects, std::vector<LanePolyline>& lanes,
                      const std::vector<HeadingTrig>* trig) {
  static const std::vector<SceneryBox> none;
  apply(objects, lanes, none, trig);
}

void Occlusion::apply(std::vector<Object>& objects, std::vector<LanePolyline>& lanes,
                      const std::vector<SceneryBox>& scenery, const std::vector<HeadingTrig>* trig) {
  // Reset only the runs of cells the previous frame wrote (a full clear costs more than a frame of boxes).
  for (const auto& [start, len] : written_) {
    std::fill_n(depth_.begin() + start, len, std::numeric_limits<float>::infinity());
    std::fill_n(owner_.begin() + start, len, -1);
  }
  written_.clear();
  // Objects are indices [0, n), scenery boxes [n, n + m): both take part in the depth test, only
  // the objects' counts become visible fractions.
  const int n = static_cast<int>(objects.size()), m = static_cast<int>(scenery.size());
  footprint_.assign(n + m, 0);
  visible_.assign(n + m, 0);
  // Nearest first: a nearer box then rarely has to take cells from one drawn before it (the
  // result does not depend on the order; the work does).
  order_.resize(n + m);
  key_.resize(n + m);
  dist_.resize(n + m);
  for (int i = 0; i < n + m; ++i) {
    const Eigen::Vector3d& p = i < n ? objects[i].position : scenery[i - n].position;
    const Eigen::Vector3d& size = i < n ? objects[i].size : scenery[i - n].size;
    order_[i] = i;
    dist_[i] = std::hypot(p.x(), p.y());
    key_[i] = dist_[i] - 0.5 * size.head<2>().norm();
  }
  std::sort(order_.begin(), order_.end(), [&](int a, int b) { return key_[a] < key_[b]; });
  for (int i : order_) {
    if (i < n)
      rasterise(objects[i].position, objects[i].size, i, trig ? (*trig)[i] : HeadingTrig::of(objects[i].heading),
                dist_[i]);
    else
      rasterise(scenery[i - n].position, scenery[i - n].size, i, HeadingTrig::of(scenery[i - n].heading), dist_[i]);
  }
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
