#include "sensor/fov.h"
#include "sensor/frames.h"

#include <algorithm>
#include <limits>
#include "common/angles.h"

namespace lidarsim::sensor {

namespace {



bool full_circle(const FieldOfView& fov) { return fov.azimuth_max - fov.azimuth_min >= 2 * kPi - 1e-12; }

// Bounds on z / horizontal distance that are surely inside the vertical limits: a point whose
// ratio lies in [lo, hi] has atan2(z, hypot(x, y)) inside [elevation_min, elevation_max] with a
// margin of 1e-6 rad, a million times the rounding of the ratio, hypot and atan2. So a box whose
// points all fall inside needs no atan2: the elevation test passes and nothing is truncated in
// elevation (the exact path then gives exactly these answers; near the limits it still runs).
struct SafeRatios {
  double lo = std::numeric_limits<double>::infinity(), hi = -std::numeric_limits<double>::infinity();  // none
  explicit SafeRatios(const FieldOfView& fov) {
    constexpr double margin = 1e-6, edge = kPi / 2 - 1e-3;
    const double top = fov.elevation_max - margin, bottom = fov.elevation_min + margin;
    if (!(top > bottom)) return;
    hi = top >= edge ? (fov.elevation_max >= kPi / 2 ? std::numeric_limits<double>::max() : std::tan(edge)) : std::tan(top);
    lo = bottom <= -edge ? (fov.elevation_min <= -kPi / 2 ? -std::numeric_limits<double>::max() : std::tan(-edge))
                         : std::tan(bottom);
  }
  // All n ratios finite and inside.
  bool inside(const double* k, int n) const {
    bool ok = true;
    for (int i = 0; i < n; ++i) ok &= k[i] >= lo && k[i] <= hi;  // false for NaN and +-inf beyond max
    return ok;
  }
};

void corners_of(const Object& o, double c, double s, Eigen::Vector3d corners[8]) {
  const Eigen::Vector3d half = 0.5 * o.size;
  int k = 0;
  for (int ix = -1; ix <= 1; ix += 2)
    for (int iy = -1; iy <= 1; iy += 2)
      for (int iz = -1; iz <= 1; iz += 2) {
        const double lx = ix * half.x(), ly = iy * half.y();
        corners[k++] = o.position + Eigen::Vector3d(c * lx - s * ly, s * lx + c * ly, iz * half.z());
      }
}

Eigen::Vector3d closest_point(const Object& o, double c, double s, const Eigen::Vector3d& p) {
  const Eigen::Vector3d d = p - o.position;
  Eigen::Vector3d local(c * d.x() + s * d.y(), -s * d.x() + c * d.y(), d.z());
  const Eigen::Vector3d half = 0.5 * o.size;
  local = local.cwiseMax(-half).cwiseMin(half);
  return o.position + Eigen::Vector3d(c * local.x() - s * local.y(), s * local.x() + c * local.y(), local.z());
}

// What the field-of-view test and the truncation share for one box, computed once (apply_fov
// runs both): heading's cos / sin, the corners (and the centre and the point nearest the sensor
// after them), each point's z / horizontal distance, and the elevations taken so far.
// Elevation atan2(z, hypot(x, y)) is monotone in z / hypot(x, y), so extremes are found on that
// ratio and only they pay for atan2.
struct BoxGeometry {
  const Object& o;
  double c, s;
  Eigen::Vector3d pts[10];  // 8 corners, centre, nearest point (the last two once with_near())
  double k[10];
  double el[10];
  bool has_el[10] = {};
  bool has_near = false;
  explicit BoxGeometry(const Object& obj, HeadingTrig h) : o(obj), c(h.c), s(h.s) {
    corners_of(o, c, s, pts);
    for (int i = 0; i < 8; ++i) k[i] = ratio(pts[i]);
  }
  static double ratio(const Eigen::Vector3d& p) { return p.z() / std::sqrt(p.x() * p.x() + p.y() * p.y()); }
  const Eigen::Vector3d& with_near() {
    if (!has_near) {
      pts[8] = o.position;
      pts[9] = closest_point(o, c, s, Eigen::Vector3d::Zero());
      k[8] = ratio(pts[8]);
      k[9] = ratio(pts[9]);
      has_near = true;
    }
    return pts[9];
  }
  double elevation(int i) {
    if (!has_el[i]) {
      el[i] = std::atan2(pts[i].z(), std::hypot(pts[i].x(), pts[i].y()));
      has_el[i] = true;
    }
    return el[i];
  }
  // Lowest and highest elevation over the first n points (first index on ties).
  void elevation_extremes(int n, double& el_lo, double& el_hi) {
    int i_lo = 0, i_hi = 0;
    double k_lo = std::numeric_limits<double>::infinity(), k_hi = -k_lo;
    for (int i = 0; i < n; ++i) {
      if (k[i] < k_lo) k_lo = k[i], i_lo = i;
      if (k[i] > k_hi) k_hi = k[i], i_hi = i;
    }
    el_lo = elevation(i_lo);
    el_hi = elevation(i_hi);
  }
  // The box's point nearest the sensor's vertical axis at the box's height.
  Eigen::Vector3d below() const { return closest_point(o, c, s, Eigen::Vector3d(0, 0, o.position.z())); }
};

bool in_fov(BoxGeometry& g, const FieldOfView& fov, const SafeRatios& safe) {
  const Eigen::Vector3d nearest = g.with_near();
  const double r_near = nearest.norm();
  if (r_near > fov.range_max) return false;
  // The largest norm is the root of the largest squared norm (sqrt is monotone and correctly rounded).
  double r2_far = 0;
  for (const auto& p : g.pts) r2_far = std::max(r2_far, p.squaredNorm());
  if (std::sqrt(r2_far) < fov.range_min) return false;
  if (r_near == 0) return true;  // the sensor is inside the box: every direction sees it

  // Elevation interval first (a full-circle field of view needs no azimuths).
  if (!safe.inside(g.k, 10)) {
    double el_lo = 0, el_hi = 0;
    g.elevation_extremes(10, el_lo, el_hi);
    if (el_hi < fov.elevation_min || el_lo > fov.elevation_max) return false;
  }
  if (full_circle(fov)) return true;
  // Angular interval of the sample points, azimuths taken relative to the centre direction so
  // that a box across the +-pi seam stays one interval.
  const double az_ref = std::atan2(nearest.y(), nearest.x());
  double az_lo = 1e9, az_hi = -1e9;
  for (const auto& p : g.pts) {
    const double rel = wrap_pi(std::atan2(p.y(), p.x()) - az_ref);
    az_lo = std::min(az_lo, rel);
    az_hi = std::max(az_hi, rel);
  }
  // Sensor straight above or below the box: it spans every azimuth.
  const Eigen::Vector3d below = g.below();
  if (below.x() == 0 && below.y() == 0) return true;  // hypot(x, y) == 0
  // The FoV interval relative to the same reference, tested on the circle (three windings).
  const double f_lo = wrap_pi(fov.azimuth_min - az_ref);
  const double width = fov.azimuth_max - fov.azimuth_min;
  for (int k = -1; k <= 1; ++k) {
    const double lo = f_lo + 2 * kPi * k, hi = lo + width;
    if (az_hi >= lo && az_lo <= hi) return true;
  }
  return false;
}

double truncation(BoxGeometry& g, const FieldOfView& fov, const SafeRatios& safe) {
  const Object& o = g.o;
  const Eigen::Vector3d* corners = g.pts;
  const Eigen::Vector3d below = g.below();
  const bool on_axis = below.x() == 0 && below.y() == 0;  // hypot(x, y) == 0
  // Every corner surely inside the vertical limits, every azimuth in view: the shares below are
  // 1 / 1 in azimuth and el_in / el_span = 1 exactly in elevation, so the result is 0.
  if (!on_axis && full_circle(fov) && safe.inside(g.k, 8)) return 0.0;
  double el_lo = kPi, el_hi = -kPi;
  g.elevation_extremes(8, el_lo, el_hi);
  const double width = std::min(fov.azimuth_max - fov.azimuth_min, 2 * kPi);
  double az_span = 0, az_in = 0;
  if (on_axis) {
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
      for (int i = 0; i < 8; ++i) {
        const Eigen::Vector3d& p = corners[i];
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

}  // namespace

void box_corners(const Object& o, Eigen::Vector3d corners[8]) { corners_of(o, std::cos(o.heading), std::sin(o.heading), corners); }

Eigen::Vector3d closest_point_on_box(const Object& o, const Eigen::Vector3d& p) {
  return closest_point(o, std::cos(o.heading), std::sin(o.heading), p);
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
  BoxGeometry g(o, HeadingTrig::of(o.heading));
  return in_fov(g, fov, SafeRatios(fov));
}

double fov_truncation(const Object& o, const FieldOfView& fov) {
  BoxGeometry g(o, HeadingTrig::of(o.heading));
  return truncation(g, fov, SafeRatios(fov));
}

int apply_fov(std::vector<Object>& objects, const FieldOfView& fov, std::vector<HeadingTrig>* trig) {
  // One pass: both tests on one BoxGeometry (the kept objects move up, in order, as erase_if would).
  const std::size_t before = objects.size();
  std::size_t kept = 0;
  const SafeRatios safe(fov);
  if (trig) trig->resize(before);
  for (std::size_t i = 0; i < before; ++i) {
    const HeadingTrig h = HeadingTrig::of(objects[i].heading);
    BoxGeometry g(objects[i], h);
    if (!in_fov(g, fov, safe)) continue;
    const double t = truncation(g, fov, safe);
    if (kept != i) objects[kept] = std::move(objects[i]);
    if (trig) (*trig)[kept] = h;
    objects[kept++].truncation = t;
  }
  objects.resize(kept);
  if (trig) trig->resize(kept);
  return static_cast<int>(before - kept);
}

void apply_fov_to_lanes(std::vector<LanePolyline>& lanes, const FieldOfView& fov) {
  for (auto& lane : lanes)
    std::erase_if(lane.points, [&](const Eigen::Vector3d& p) { return !point_in_fov(p, fov); });
  std::erase_if(lanes, [](const LanePolyline& l) { return l.points.size() < 2; });
}

}  // namespace lidarsim::sensor
