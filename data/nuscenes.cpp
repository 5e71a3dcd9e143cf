#include "data/nuscenes.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <tuple>

#include "common/error.h"
#include "data/binary_file.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

std::vector<pgm::Point> read_nuscenes_pcd_bin(const fs::path& path) {
  const std::vector<char> bytes = read_binary_file(path);
  constexpr std::size_t kPoint = 5 * sizeof(float);
  if (bytes.size() % kPoint != 0)
    throw input_error(path.string(), "size",
                      std::to_string(bytes.size()) + " bytes is not a multiple of 20 (float32 x, y, z, intensity, ring "
                      "per point): the file is truncated or not a nuScenes .pcd.bin");
  const std::size_t n = bytes.size() / kPoint;
  std::vector<pgm::Point> points(n);
  for (std::size_t i = 0; i < n; ++i) {
    float v[5];
    std::memcpy(v, bytes.data() + i * kPoint, kPoint);
    for (int k = 0; k < 5; ++k) {
      if (!std::isfinite(v[k])) {
        static const char* names[5] = {"x", "y", "z", "intensity", "ring"};
        throw input_error(path.string(), "point " + std::to_string(i) + " " + names[k], "not a finite number (NaN or Inf)");
      }
    }
    // Range first: casting a float beyond int's range is undefined (found by fuzz/ nuscenes).
    if (!(v[4] >= 0.f && v[4] < static_cast<float>(kNuscenesRings)) || v[4] != std::floor(v[4]))
      throw input_error(path.string(), "point " + std::to_string(i) + " ring",
                        "expected an integer 0-31 (HDL-32E), got " + std::to_string(v[4]));
    if (v[3] < 0.f || v[3] > 255.f)
      throw input_error(path.string(), "point " + std::to_string(i) + " intensity",
                        "expected 0-255, got " + std::to_string(v[3]));
    pgm::Point& p = points[i];
    p.x = v[1];   // nuScenes y (forward) -> our x
    p.y = -v[0];  // nuScenes x (right) -> our -y (left)
    p.z = v[2];
    p.intensity = v[3] / 255.f;
    p.ring = kNuscenesRings - 1 - static_cast<int>(v[4]);
  }
  return points;
}

std::vector<NuscenesFile> list_nuscenes(const fs::path& dir) {
  std::vector<fs::path> files;
  const auto is_sweep = [](const fs::path& p) {
    const std::string name = p.filename().string();
    return name.size() > 8 && name.compare(name.size() - 8, 8, ".pcd.bin") == 0;
  };
  std::error_code ec;
  if (fs::is_regular_file(dir, ec)) {
    files.push_back(dir);
  } else if (fs::is_directory(dir, ec)) {
    for (const auto& e : fs::recursive_directory_iterator(dir))
      if (e.is_regular_file() && is_sweep(e.path())) files.push_back(e.path());
  } else {
    throw input_error(dir.string(), "folder", "not found");
  }
  std::vector<NuscenesFile> out;
  for (const auto& f : files) {
    if (!is_sweep(f)) throw input_error(f.string(), "name", "expected a .pcd.bin file");
    std::string stem = f.filename().string();
    stem.resize(stem.size() - 8);
    const std::string tag = "__LIDAR_TOP__";
    const auto at = stem.find(tag);
    if (at == std::string::npos) out.push_back({"", stem, f});
    else out.push_back({stem.substr(0, at), stem.substr(at + tag.size()), f});
  }
  std::sort(out.begin(), out.end(), [](const NuscenesFile& a, const NuscenesFile& b) {
    return std::tie(a.log, a.timestamp) < std::tie(b.log, b.timestamp);
  });
  return out;
}

}  // namespace lidarsim::data
