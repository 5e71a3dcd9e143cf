#pragma once
// PLY point clouds (binary little-endian or ASCII, one "vertex" element read; other elements
// after it are ignored), every vertex property as a float column by name. Enough for recorded
// clouds that carry sensor fields (ring, reflectivity, t, ...) beside x, y, z.
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace lidarsim::data {

struct PlyCloud {
  std::vector<std::string> properties;               // in file order
  std::map<std::string, std::vector<double>> column;  // property -> one value per vertex
  std::size_t size() const { return column.empty() ? 0 : column.begin()->second.size(); }
  // The column of `name`; throws naming the file and the property when it is missing.
  const std::vector<double>& at(const std::string& name) const;
  std::string path;
};

PlyCloud read_ply(const std::filesystem::path& path);

}  // namespace lidarsim::data
