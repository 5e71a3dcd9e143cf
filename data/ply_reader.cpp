#include "data/ply_reader.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <sstream>

#include "common/error.h"
#include "data/binary_file.h"

namespace lidarsim::data {
namespace {

struct Property {
  std::string name;
  std::string type;
  int bytes = 0;
};

int type_bytes(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

template <typename T>
double load(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return static_cast<double>(v);
}

double decode(const std::string& t, const char* p) {
  if (t == "char" || t == "int8") return load<std::int8_t>(p);
  if (t == "uchar" || t == "uint8") return load<std::uint8_t>(p);
  if (t == "short" || t == "int16") return load<std::int16_t>(p);
  if (t == "ushort" || t == "uint16") return load<std::uint16_t>(p);
  if (t == "int" || t == "int32") return load<std::int32_t>(p);
  if (t == "uint" || t == "uint32") return load<std::uint32_t>(p);
  if (t == "float" || t == "float32") return load<float>(p);
  return load<double>(p);
}

}  // namespace

const std::vector<double>& PlyCloud::at(const std::string& name) const {
  auto it = column.find(name);
  if (it == column.end()) throw input_error(path, "property " + name, "missing");
  return it->second;
}

PlyCloud read_ply(const std::filesystem::path& path) {
  const std::vector<char> bytes = read_binary_file(path);
  const std::string fname = path.string();
  const std::string text(bytes.data(), std::min<std::size_t>(bytes.size(), 64 * 1024));
  const auto end = text.find("end_header\n");
  if (text.rfind("ply", 0) != 0 || end == std::string::npos)
    throw input_error(fname, "header", "not a PLY file (expected 'ply' ... 'end_header')");
  std::istringstream header(text.substr(0, end));
  std::string line, format;
  std::size_t vertices = 0;
  bool in_vertex = false, seen_vertex = false;
  std::vector<Property> props;
  while (std::getline(header, line)) {
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") {
      ls >> format;
    } else if (word == "element") {
      std::string name;
      std::size_t count = 0;
      ls >> name >> count;
      in_vertex = name == "vertex";
      if (in_vertex) vertices = count, seen_vertex = true;
      else if (!seen_vertex && count > 0)
        throw input_error(fname, "element " + name, "comes before the vertices (not supported)");
    } else if (word == "property" && in_vertex) {
      Property p;
      ls >> p.type;
      if (p.type == "list") throw input_error(fname, "vertex property", "list properties are not supported");
      ls >> p.name;
      p.bytes = type_bytes(p.type);
      if (!p.bytes) throw input_error(fname, "property " + p.name, "unknown type '" + p.type + "'");
      props.push_back(p);
    }
  }
  if (!seen_vertex || props.empty()) throw input_error(fname, "element vertex", "missing");
  // The count is the header's word: measure it against the data before allocating for it (a
  // binary vertex takes its stride, an ASCII value at least a digit and a separator, none after the last).
  const std::size_t data_start = end + std::strlen("end_header\n");
  const std::size_t available = bytes.size() - data_start + (format == "ascii" ? 1 : 0);
  std::size_t stride = 0;
  for (const auto& p : props) stride += p.bytes;
  const std::size_t per_vertex = format == "ascii" ? 2 * props.size() : stride;
  if (vertices > available / per_vertex)
    throw input_error(fname, "element vertex", "says " + std::to_string(vertices) + " vertices, the file holds " +
                                                   std::to_string(bytes.size() - data_start) + " bytes of data (" +
                                                   std::to_string(per_vertex) + " at least per vertex)");
  PlyCloud cloud;
  cloud.path = fname;
  for (const auto& p : props) {
    cloud.properties.push_back(p.name);
    cloud.column[p.name].resize(vertices);
  }
  if (format == "binary_little_endian") {
    for (std::size_t v = 0; v < vertices; ++v) {
      const char* row = bytes.data() + data_start + v * stride;
      for (const auto& p : props) {
        cloud.column[p.name][v] = decode(p.type, row);
        row += p.bytes;
      }
    }
  } else if (format == "ascii") {
    std::istringstream body(std::string(bytes.data() + data_start, bytes.size() - data_start));
    for (std::size_t v = 0; v < vertices; ++v)
      for (const auto& p : props)
        if (!(body >> cloud.column[p.name][v]))
          throw input_error(fname, "vertex " + std::to_string(v) + " " + p.name, "missing or not a number");
  } else {
    throw input_error(fname, "format", "'" + format + "' not supported (binary_little_endian or ascii)");
  }
  return cloud;
}

}  // namespace lidarsim::data
