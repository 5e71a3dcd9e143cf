#pragma once
// Limits beyond which a recorded value cannot be real; the readers reject such input with an
// Error naming file and field rather than carrying on with garbage, so no downstream number is
// computed from a value no sensor could record.
#include <charconv>
#include <string>

namespace lidarsim::data {

constexpr double kMaxPointCoordinate = 2000.0;  // m from the sensor: far beyond any LiDAR's range
constexpr double kMaxBoxSize = 100.0;           // m, any of a box's h, w, l
constexpr double kMaxBoxPosition = 10000.0;     // m, any coordinate of a box's position
constexpr int kMaxFrameIndex = 1000000;         // frames of one sequence (KITTI's longest: 1,100)
constexpr double kMinSingularDeterminant = 1e-6;  // |det| of a rotation part below this is singular

// The whole token as a number (no trailing junk such as "6.93x-03"); false otherwise.
inline bool parse_double(const std::string& token, double& out) {
  const char* begin = token.data();
  const char* end = begin + token.size();
  if (begin != end && *begin == '+') ++begin;  // from_chars takes no sign '+'
  const auto res = std::from_chars(begin, end, out);
  return res.ec == std::errc() && res.ptr == end && begin != end;
}

}  // namespace lidarsim::data
