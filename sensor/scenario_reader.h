#pragma once
// The scenario reader's JSON access (sensor/scenario.cpp, sensor/scenery.cpp): every field is
// read through a Reader, which checks its type and range and names the file and the JSON path of
// anything wrong ("file: objects[3].size[1]: must be positive, got -2").
#include <nlohmann/json.hpp>

#include <Eigen/Core>

#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "common/error.h"
#include "sensor/scene.h"

namespace lidarsim::sensor::scenario_json {

using nlohmann::json;

// Prefix of the string a NaN/Infinity literal is replaced by before parsing (scenario.cpp), so
// that the field holding it can be named.
inline const std::string kNonFinite = "@@lidarsim-nonfinite@@:";

class Reader {
 public:
  static constexpr double kMaxMagnitude = 1e7;

  explicit Reader(std::string file) : file_(std::move(file)) {}

  [[noreturn]] void fail(const std::string& path, const std::string& msg) const {
    throw input_error(file_, path.empty() ? "(top level)" : path, msg);
  }

  static std::string describe(const json& j) {
    if (j.is_string()) {
      const auto& s = j.get_ref<const std::string&>();
      if (s.rfind(kNonFinite, 0) == 0) return s.substr(kNonFinite.size());
      return "\"" + s + "\"";
    }
    return j.dump();
  }

  const json& field(const json& obj, const std::string& path, const char* key) const {
    if (!obj.is_object()) fail(path, "must be an object, got " + describe(obj));
    const auto it = obj.find(key);
    if (it == obj.end()) fail(join(path, key), "missing (required field)");
    return *it;
  }
  const json* optional(const json& obj, const char* key) const {
    const auto it = obj.find(key);
    return it == obj.end() ? nullptr : &*it;
  }
  static std::string join(const std::string& path, const char* key) {
    return path.empty() ? std::string(key) : path + "." + key;
  }
  static std::string index(const std::string& path, std::size_t i) { return path + "[" + std::to_string(i) + "]"; }

  double number(const json& j, const std::string& path) const {
    if (j.is_string() && j.get_ref<const std::string&>().rfind(kNonFinite, 0) == 0)
      fail(path, "must be a finite number, got " + describe(j));
    if (!j.is_number()) fail(path, "must be a number, got " + describe(j));
    const double v = j.get<double>();
    if (!std::isfinite(v)) fail(path, "must be a finite number, got " + describe(j));
    // Metres, seconds, degrees: nothing in a scenario is this large, and bounding every number
    // bounds what is derived from them (lane resampling, frame counts).
    if (std::abs(v) > kMaxMagnitude) fail(path, "must lie within +-1e7, got " + describe(j));
    return v;
  }
  double number(const json& obj, const std::string& path, const char* key) const {
    return number(field(obj, path, key), join(path, key));
  }
  double positive(const json& obj, const std::string& path, const char* key) const {
    const double v = number(obj, path, key);
    if (!(v > 0)) fail(join(path, key), "must be positive, got " + fmt(v));
    return v;
  }
  int integer(const json& obj, const std::string& path, const char* key, int min_value) const {
    const auto& j = field(obj, path, key);
    const double v = number(j, join(path, key));
    if (v != std::floor(v) || std::abs(v) > 1e9) fail(join(path, key), "must be an integer, got " + describe(j));
    if (v < min_value) fail(join(path, key), "must be at least " + std::to_string(min_value) + ", got " + describe(j));
    return static_cast<int>(v);
  }
  std::string string(const json& obj, const std::string& path, const char* key) const {
    const auto& j = field(obj, path, key);
    if (!j.is_string() || j.get_ref<const std::string&>().rfind(kNonFinite, 0) == 0)
      fail(join(path, key), "must be a string, got " + describe(j));
    return j.get<std::string>();
  }
  bool boolean(const json& obj, const std::string& path, const char* key) const {
    const auto& j = field(obj, path, key);
    if (!j.is_boolean()) fail(join(path, key), "must be true or false, got " + describe(j));
    return j.get<bool>();
  }
  const json& array(const json& obj, const std::string& path, const char* key, std::size_t min_size) const {
    const auto& j = field(obj, path, key);
    if (!j.is_array()) fail(join(path, key), "must be an array, got " + describe(j));
    if (j.size() < min_size)
      fail(join(path, key), "must have at least " + std::to_string(min_size) + " entries, got " + std::to_string(j.size()));
    return j;
  }
  Eigen::Vector3d vec(const json& j, const std::string& path, std::size_t min_len = 3) const {
    if (!j.is_array() || j.size() < min_len || j.size() > 3)
      fail(path, (min_len == 3 ? "must be an array of 3 numbers, got " : "must be an array of 2 or 3 numbers, got ") +
                     describe(j));
    Eigen::Vector3d v = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < j.size(); ++i) v[static_cast<int>(i)] = number(j[i], index(path, i));
    return v;
  }
  Eigen::Vector3d vec(const json& obj, const std::string& path, const char* key) const {
    return vec(field(obj, path, key), join(path, key));
  }
  static std::string fmt(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
  }

 private:
  std::string file_;
};

// The optional "scenery" array of a scenario's root as boxes in the map frame (sensor/scenery.h
// describes the format; sensor/scenery.cpp reads it).
std::vector<SceneryBox> read_scenery(const Reader& r, const json& root);

}  // namespace lidarsim::sensor::scenario_json
