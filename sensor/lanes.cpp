#include "sensor/lanes.h"

#include <Eigen/Dense>

#include <algorithm>

namespace lidarsim::sensor {

bool fit_lane(const LanePolyline& lane, LanePolynomial& out, const LaneFitConfig& config) {
  const int n = static_cast<int>(lane.points.size());
  if (n < std::max(2, config.min_points)) return false;
  double x_min = lane.points[0].x(), x_max = x_min;
  for (const auto& p : lane.points) {
    x_min = std::min(x_min, p.x());
    x_max = std::max(x_max, p.x());
  }
  if (x_max - x_min < config.min_x_span) return false;
  const double mid = 0.5 * (x_max + x_min), half = 0.5 * (x_max - x_min);
  const int degree = std::min(3, n - 1);
  // Normal equations of the scaled problem, 4x4 at most: no per-point allocation.
  Eigen::Matrix4d ata = Eigen::Matrix4d::Zero();
  Eigen::Vector4d aty = Eigen::Vector4d::Zero();
  for (const auto& p : lane.points) {
    const double u = (p.x() - mid) / half;
    Eigen::Vector4d row(1, u, u * u, u * u * u);
    ata.noalias() += row * row.transpose();
    aty.noalias() += row * p.y();
  }
  const int m = degree + 1;
  Eigen::Vector4d a = Eigen::Vector4d::Zero();
  a.head(m) = ata.topLeftCorner(m, m).ldlt().solve(aty.head(m));
  // y = sum a_k ((x - mid)/half)^k  ->  sum c_k x^k.
  const double s = 1.0 / half, m0 = -mid / half;  // u = s x + m0
  // Expand (s x + m0)^k.
  const double c0 = a[0] + a[1] * m0 + a[2] * m0 * m0 + a[3] * m0 * m0 * m0;
  const double c1 = a[1] * s + 2 * a[2] * s * m0 + 3 * a[3] * s * m0 * m0;
  const double c2 = a[2] * s * s + 3 * a[3] * s * s * m0;
  const double c3 = a[3] * s * s * s;
  out.id = lane.id;
  out.type = lane.type;
  out.c0 = c0;
  out.c1 = c1;
  out.c2 = c2;
  out.c3 = c3;
  out.x_min = x_min;
  out.x_max = x_max;
  return true;
}

void fit_lanes(const std::vector<LanePolyline>& lanes, std::vector<LanePolynomial>& out, const LaneFitConfig& config) {
  out.clear();
  LanePolynomial p;
  for (const auto& lane : lanes)
    if (fit_lane(lane, p, config)) out.push_back(p);
}

double evaluate(const LanePolynomial& p, double x) { return p.c0 + x * (p.c1 + x * (p.c2 + x * p.c3)); }

}  // namespace lidarsim::sensor
