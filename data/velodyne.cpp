#include "data/velodyne.h"

#include <cmath>
#include <cstring>
#include <fstream>

#include "common/error.h"

namespace lidarsim::data {
namespace {

std::vector<char> read_all(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw input_error(path.string(), "file", "not found or not a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw input_error(path.string(), "file", "cannot be opened");
  std::vector<char> bytes(std::filesystem::file_size(path));
  if (!bytes.empty() && !in.read(bytes.data(), static_cast<std::streamsize>(bytes.size())))
    throw input_error(path.string(), "file", "read failed");
  return bytes;
}

}  // namespace

std::vector<pgm::Point> read_velodyne_bin(const std::filesystem::path& path) {
  const std::vector<char> bytes = read_all(path);
  if (bytes.size() % 16 != 0)
    throw input_error(path.string(), "size",
                      std::to_string(bytes.size()) + " bytes is not a multiple of 16 (float32 x, y, z, reflectance "
                      "per point): the file is truncated or not a Velodyne .bin");
  const std::size_t n = bytes.size() / 16;
  std::vector<pgm::Point> points(n);
  for (std::size_t i = 0; i < n; ++i) {
    float v[4];
    std::memcpy(v, bytes.data() + i * 16, 16);  // the files are little-endian, as is every host we build on
    for (int k = 0; k < 4; ++k) {
      if (!std::isfinite(v[k])) {
        static const char* names[4] = {"x", "y", "z", "reflectance"};
        throw input_error(path.string(), "point " + std::to_string(i) + " " + names[k],
                          "not a finite number (NaN or Inf)");
      }
    }
    points[i].x = v[0];
    points[i].y = v[1];
    points[i].z = v[2];
    points[i].intensity = v[3];
  }
  return points;
}

std::vector<std::uint32_t> read_label_file(const std::filesystem::path& path, std::size_t expected_count) {
  const std::vector<char> bytes = read_all(path);
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
