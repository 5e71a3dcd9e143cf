#pragma once
// KITTI-style binary point files, read as they are:
//   *.bin   little-endian float32 records (x, y, z, reflectance), 16 bytes per point, Velodyne
//           frame (x forward, y left, z up, metres)
//   *.label little-endian uint32 per point, same order; lower 16 bits = SemanticKITTI class,
//           upper 16 bits = instance id
// Errors are lidarsim::Error "file: field: what is wrong": a size that is not a multiple of 16,
// a label count different from the point count, a non-finite coordinate or reflectance.
#include <cstdint>
#include <filesystem>
#include <vector>

#include "pgm/projection.h"

namespace lidarsim::data {

// Points with intensity = reflectance; class and material 0, ring -1.
std::vector<pgm::Point> read_velodyne_bin(const std::filesystem::path& path);
// Raw uint32 labels; throws unless there are exactly `expected_count` of them.
std::vector<std::uint32_t> read_label_file(const std::filesystem::path& path, std::size_t expected_count);

}  // namespace lidarsim::data
