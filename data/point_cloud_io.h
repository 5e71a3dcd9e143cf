#pragma once
// Point clouds out: binary PCD (v0.7) and binary little-endian PLY, the formats PCL, Open3D and
// CloudCompare open. Every field is float32; x, y, z come first, any further named scalar
// fields (intensity, predicted intensity, class, ...) follow and show up as scalar fields.
#include <filesystem>
#include <string>
#include <vector>

namespace lidarsim::data {

struct PointCloud {
  std::vector<std::string> fields;          // "x", "y", "z", then any others
  std::vector<std::vector<float>> columns;  // one per field, all the same length

  std::size_t size() const { return columns.empty() ? 0 : columns[0].size(); }
  void add_field(const std::string& name, std::vector<float> values);  // checks the length
};

// Writes by extension: ".pcd" or ".ply" (atomically); anything else is an error naming the path.
void write_point_cloud(const std::filesystem::path& path, const PointCloud& cloud);
void write_pcd(const std::filesystem::path& path, const PointCloud& cloud);
void write_ply(const std::filesystem::path& path, const PointCloud& cloud);

}  // namespace lidarsim::data
