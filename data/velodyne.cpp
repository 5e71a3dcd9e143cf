#include "data/velodyne.h"

#include <cmath>
#include <cstring>

#include "common/error.h"
#include "data/binary_file.h"
#include "data/plausibility.h"

namespace lidarsim::data {

std::vector<pgm::Point> read_velodyne_bin(const std::filesystem::path& path) {
  const std::vector<char> bytes = read_binary_file(path);
  if (bytes.size() % 16 != 0)
    throw input_error(path.string(), "size",
                      std::to_string(bytes.size()) + " bytes is not a multiple of 16 (float32 x, y, z, reflectance "
                      "per point): the file is truncated or not a Velodyne .bin");
  const std::size_t n = bytes.size() / 16;
  if (n == 0) throw input_error(path.string(), "size", "empty scan (0 points)");
  std::vector<pgm::Point> points(n);
  static const char* names[4] = {"x", "y", "z", "reflectance"};
  bool any_return = false;
  for (std::size_t i = 0; i < n; ++i) {
    float v[4];
    std::memcpy(v, bytes.data() + i * 16, 16);  // the files are little-endian, as is every host we build on
    for (int k = 0; k < 4; ++k) {
      if (!std::isfinite(v[k])) {
        throw input_error(path.string(), "point " + std::to_string(i) + " " + names[k],
                          "not a finite number (NaN or Inf)");
      }
      if (k < 3 && std::abs(v[k]) > kMaxPointCoordinate)
        throw input_error(path.string(), "point " + std::to_string(i) + " " + names[k],
                          std::to_string(v[k]) + " m is beyond any LiDAR's range (limit " +
                              std::to_string(static_cast<int>(kMaxPointCoordinate)) + " m)");
    }
    if (!(v[3] >= 0.f && v[3] <= 1.f))
      throw input_error(path.string(), "point " + std::to_string(i) + " reflectance",
                        std::to_string(v[3]) + " is outside [0, 1] (KITTI's reflectance scale)");
    any_return = any_return || v[0] != 0.f || v[1] != 0.f || v[2] != 0.f;
    points[i].x = v[0];
    points[i].y = v[1];
    points[i].z = v[2];
    points[i].intensity = v[3];
  }
  if (!any_return) throw input_error(path.string(), "points", "all points are at the origin (0, 0, 0): no return in the scan");
  return points;
}

std::vector<std::uint32_t> read_label_file(const std::filesystem::path& path, std::size_t expected_count) {
  const std::vector<char> bytes = read_binary_file(path);
  if (bytes.size() % 4 != 0)
    throw input_error(path.string(), "size", std::to_string(bytes.size()) + " bytes is not a multiple of 4 (uint32 per point)");
  const std::size_t n = bytes.size() / 4;
  if (n != expected_count)
    throw input_error(path.string(), "label count",
                      "has " + std::to_string(n) + " labels but its scan has " + std::to_string(expected_count) +
                          " points (one uint32 label per point expected)");
  std::vector<std::uint32_t> labels(n);
  if (n) std::memcpy(labels.data(), bytes.data(), bytes.size());
  return labels;
}

}  // namespace lidarsim::data
