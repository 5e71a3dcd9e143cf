#pragma once
// Cheap arctangents for bounds only: where a stage needs an angle just to decide which grid
// rows or columns to visit (occlusion), and widens the range by kAtanBoundError, a polynomial
// serves as well as libm's atan / atan2 / asin at a fraction of the cost. Never use these for a
// number that is reported: they are accurate to about 2e-6 rad, not to the last bit.
#include <cmath>
#include <numbers>

namespace lidarsim::sensor {

// |atan_bound(x) - atan(x)| <= kAtanBoundError for every finite x (tests/sensor/test_angle_bounds.cpp
// checks it on a dense grid); the same for atan2_bound and asin_bound.
inline constexpr double kAtanBoundError = 2e-6;

// Odd minimax polynomial on [0, 1] (max error 1.7e-6), 1 / |x| beyond.
inline double atan_bound(double x) {
  const double a = std::abs(x);
  const bool inv = a > 1;
  const double t = inv ? 1 / a : a, t2 = t * t;
  double p = t * (0.99997726 +
                  t2 * (-0.33262347 + t2 * (0.19354346 + t2 * (-0.11643287 + t2 * (0.05265332 + t2 * -0.01172120)))));
  if (inv) p = std::numbers::pi / 2 - p;
  return std::copysign(p, x);
}

// atan2(y, x) in (-pi, pi] (not both zero).
inline double atan2_bound(double y, double x) {
  const double ax = std::abs(x), ay = std::abs(y);
  const double t = std::min(ax, ay) / std::max(ax, ay);
  double a = atan_bound(t);                      // angle from the nearer axis
  if (ay > ax) a = std::numbers::pi / 2 - a;     // from the x axis
  if (x < 0) a = std::numbers::pi - a;
  return std::copysign(a, y);
}

// asin(x) for x in [0, 1).
inline double asin_bound(double x) { return atan_bound(x / std::sqrt((1 - x) * (1 + x))); }

}  // namespace lidarsim::sensor
