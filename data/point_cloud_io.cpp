#include "data/point_cloud_io.h"

#include <fstream>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"

namespace lidarsim::data {
namespace {

void check(const std::filesystem::path& path, const PointCloud& cloud) {
  if (cloud.fields.size() < 3 || cloud.fields[0] != "x" || cloud.fields[1] != "y" || cloud.fields[2] != "z")
    throw input_error(path.string(), "fields", "must start with x, y, z");
  if (cloud.fields.size() != cloud.columns.size())
    throw input_error(path.string(), "fields", "count differs from the number of columns");
  for (std::size_t f = 0; f < cloud.columns.size(); ++f)
    if (cloud.columns[f].size() != cloud.size())
      throw input_error(path.string(), cloud.fields[f], "length differs from x");
}

// Interleaves the columns into rows of float32, the record layout both formats use.
std::string interleaved(const PointCloud& cloud) {
  const std::size_t n = cloud.size(), f = cloud.columns.size();
  std::string bytes(n * f * sizeof(float), '\0');
  auto* out = reinterpret_cast<float*>(bytes.data());
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t k = 0; k < f; ++k) out[i * f + k] = cloud.columns[k][i];
  return bytes;
}

}  // namespace

void PointCloud::add_field(const std::string& name, std::vector<float> values) {
  if (!columns.empty() && values.size() != size())
    throw Error("point cloud field '" + name + "': " + std::to_string(values.size()) + " values for " +
                std::to_string(size()) + " points");
  fields.push_back(name);
  columns.push_back(std::move(values));
}

void write_pcd(const std::filesystem::path& path, const PointCloud& cloud) {
  check(path, cloud);
  std::ostringstream header;
  const std::size_t f = cloud.fields.size();
  header << "# .PCD v0.7 - Point Cloud Data file format (written by lidarsim)\nVERSION 0.7\nFIELDS";
  for (const auto& name : cloud.fields) header << ' ' << name;
  header << "\nSIZE";
  for (std::size_t k = 0; k < f; ++k) header << " 4";
  header << "\nTYPE";
  for (std::size_t k = 0; k < f; ++k) header << " F";
  header << "\nCOUNT";
  for (std::size_t k = 0; k < f; ++k) header << " 1";
  header << "\nWIDTH " << cloud.size() << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << cloud.size()
         << "\nDATA binary\n";
  write_file_atomically(path, header.str() + interleaved(cloud));
}

void write_ply(const std::filesystem::path& path, const PointCloud& cloud) {
  check(path, cloud);
  std::ostringstream header;
  header << "ply\nformat binary_little_endian 1.0\ncomment written by lidarsim\nelement vertex " << cloud.size()
         << "\n";
  for (const auto& name : cloud.fields) header << "property float " << name << "\n";
  header << "end_header\n";
  write_file_atomically(path, header.str() + interleaved(cloud));
}

void write_point_cloud(const std::filesystem::path& path, const PointCloud& cloud) {
  const auto ext = path.extension().string();
  if (ext == ".pcd") return write_pcd(path, cloud);
  if (ext == ".ply") return write_ply(path, cloud);
  throw input_error(path.string(), "extension", "must be .pcd or .ply, got '" + ext + "'");
}

}  // namespace lidarsim::data
