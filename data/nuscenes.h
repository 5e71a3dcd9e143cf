#pragma once
// nuScenes LIDAR_TOP sweeps (samples/LIDAR_TOP/*.pcd.bin), read as they are: float32 x, y, z,
// intensity (0-255), ring index (0-31) per point, in the LIDAR_TOP frame (x right, y forward,
// z up) of a Velodyne HDL-32E. Points come back in our sensor frame (x forward, y left: a
// rotation about z), intensity / 255 (the same 0-1 scale as KITTI's reflectance), and ring
// flipped so that row 0 is the top beam (nuScenes' ring 0 is the bottom one, -30.67 deg).
// File names are "<log>__LIDAR_TOP__<timestamp us>.pcd.bin"; the log is the drive (place).
#include <filesystem>
#include <string>
#include <vector>

#include "pgm/projection.h"

namespace lidarsim::data {

inline constexpr int kNuscenesRings = 32;

std::vector<pgm::Point> read_nuscenes_pcd_bin(const std::filesystem::path& path);

struct NuscenesFile {
  std::string log;        // "n015-2018-07-24-11-22-45+0800"
  std::string timestamp;  // "1532402927647951"
  std::filesystem::path path;
};

// Every *.pcd.bin under `dir` (or `dir` itself when it is one file), sorted by log then time.
std::vector<NuscenesFile> list_nuscenes(const std::filesystem::path& dir);

}  // namespace lidarsim::data
