// The bound arctangents (sensor/angle_bounds.h) stay within kAtanBoundError of libm's on a dense
// grid: occlusion widens its row and column ranges by a multiple of that, so a larger error
// would drop cells.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "sensor/angle_bounds.h"

namespace lidarsim::sensor {
namespace {

TEST(AngleBounds, AtanWithinItsBoundEverywhere) {
  double worst = 0;
  for (int i = -400000; i <= 400000; ++i) {
    const double x = i / 20000.0;  // [-20, 20]
    worst = std::max(worst, std::abs(atan_bound(x) - std::atan(x)));
  }
  for (double x = 20; x < 1e300; x *= 1.01) {
    worst = std::max(worst, std::abs(atan_bound(x) - std::atan(x)));
    worst = std::max(worst, std::abs(atan_bound(-x) - std::atan(-x)));
  }
  EXPECT_LE(worst, kAtanBoundError);
  EXPECT_GT(worst, 1e-7) << "a polynomial, not libm: the bound is what the callers rely on";
}

TEST(AngleBounds, Atan2WithinItsBoundOnEveryQuadrant) {
  double worst = 0;
  for (int i = 0; i < 100000; ++i) {
    const double a = -std::numbers::pi + 2 * std::numbers::pi * (i + 0.5) / 100000;
    for (const double r : {1e-3, 1.0, 250.0}) {
      const double y = r * std::sin(a), x = r * std::cos(a);
      double d = std::abs(atan2_bound(y, x) - std::atan2(y, x));
      d = std::min(d, 2 * std::numbers::pi - d);  // +-pi are the same direction
      worst = std::max(worst, d);
    }
  }
  for (const auto& [y, x] : {std::pair{0.0, 1.0}, {1.0, 0.0}, {0.0, -1.0}, {-1.0, 0.0}, {3.0, 3.0}, {-2.0, -2.0}})
    worst = std::max(worst, std::abs(atan2_bound(y, x) - std::atan2(y, x)));
  EXPECT_LE(worst, kAtanBoundError);
}

TEST(AngleBounds, AsinWithinItsBoundOnZeroToOne) {
  double worst = 0;
  for (int i = 0; i < 200000; ++i) {
    const double x = i / 200000.0;
    worst = std::max(worst, std::abs(asin_bound(x) - std::asin(x)));
  }
  EXPECT_LE(worst, kAtanBoundError);
}

}  // namespace
}  // namespace lidarsim::sensor
