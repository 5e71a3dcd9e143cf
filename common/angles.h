#pragma once
// The angle constants and the one angle wrap that every layer shares (one definition, so that files
// compiled together in a unity build do not each bring their own).
#include <cmath>
#include <numbers>

namespace lidarsim {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kTwoPi = 2.0 * std::numbers::pi;
inline constexpr double kDeg = std::numbers::pi / 180.0;  // one degree in radians

// An angle wrapped into [-pi, pi) by fmod: the planted-data generators' convention (sensor/frames.h's
// wrap_pi, which keeps +-pi and leaves small angles untouched, is the sensor model's).
inline double wrap_angle_fmod(double a) {
  a = std::fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}

}  // namespace lidarsim
