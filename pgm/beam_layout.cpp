#include "pgm/beam_layout.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/angles.h"
#include "common/error.h"

namespace lidarsim::pgm {
namespace {


// Median elevation (deg) of each row of KITTI seq 00 scans 000000-000005, rows cut where the
// stored azimuth wraps (points beyond 2 m horizontally); see BeamLayout::hdl64e.
constexpr double kHdl64eKittiDeg[64] = {
    2.61,    2.233,   1.985,   1.54,    1.25,    0.838,   0.567,   0.183,   -0.163,  -0.572,  -0.868,
    -1.21,   -1.565,  -1.865,  -2.171,  -2.523,  -2.839,  -3.241,  -3.516,  -3.913,  -4.217,  -4.582,
    -4.889,  -5.182,  -5.546,  -5.856,  -6.15,   -6.415,  -6.781,  -7.143,  -7.381,  -7.766,  -8.395,
    -8.913,  -9.373,  -9.763,  -10.221, -10.822, -11.318, -11.743, -12.196, -12.62,  -13.15,  -13.668,
    -14.24,  -14.679, -15.177, -15.545, -16.169, -16.694, -17.257, -17.714, -18.209, -18.628, -19.068,
    -19.626, -20.126, -20.785, -21.259, -21.678, -22.113, -22.751, -23.231, -23.743};

}  // namespace

BeamLayout BeamLayout::uniform(int rows, double top_deg, double bottom_deg, int columns) {
  if (rows < 1 || rows > kMaxRows)
    throw Error("beam layout: rows: must be in [1, " + std::to_string(kMaxRows) + "], got " + std::to_string(rows));
  BeamLayout layout;
  layout.name = "uniform";
  layout.columns = columns;
  layout.elevations_rad.resize(rows);
  for (int r = 0; r < rows; ++r) {
    const double t = rows == 1 ? 0.0 : static_cast<double>(r) / (rows - 1);
    layout.elevations_rad[r] = (top_deg + t * (bottom_deg - top_deg)) * kDeg;
  }
  layout.validate("uniform beam layout");
  return layout;
}

BeamLayout BeamLayout::hdl64e(int columns) {
  return from_elevations_deg("hdl64e", std::vector<double>(std::begin(kHdl64eKittiDeg), std::end(kHdl64eKittiDeg)),
                             columns);
}

BeamLayout BeamLayout::from_elevations_deg(std::string name, std::vector<double> elevations_deg, int columns) {
  BeamLayout layout;
  layout.name = std::move(name);
  layout.columns = columns;
  for (double e : elevations_deg) {
    if (!std::isfinite(e)) throw Error("beam layout " + layout.name + ": elevations_deg: must be finite");
  }
  std::sort(elevations_deg.begin(), elevations_deg.end(), std::greater<>());
  for (double e : elevations_deg) layout.elevations_rad.push_back(e * kDeg);
  layout.validate("beam layout " + layout.name);
  return layout;
}

int BeamLayout::column_of(double x, double y) const {
  double az = std::atan2(y, x);
  if (az < 0) az += kTwoPi;
  int col = static_cast<int>(std::floor(az / kTwoPi * columns));
  // az may round to exactly 2pi for tiny negative angles.
  return std::clamp(col, 0, columns - 1);
}

double BeamLayout::azimuth_of_column(int col) const { return (col + 0.5) * kTwoPi / columns; }

int BeamLayout::nearest_row(double elevation_rad) const {
  const int n = rows();
  if (n == 0) return -1;
  if (n == 1) return 0;
  const double top_gap = elevations_rad[0] - elevations_rad[1];
  const double bottom_gap = elevations_rad[n - 2] - elevations_rad[n - 1];
  if (elevation_rad > elevations_rad[0] + top_gap || elevation_rad < elevations_rad[n - 1] - bottom_gap) return -1;
  // Elevations are descending: find the first row at or below the elevation.
  auto it = std::lower_bound(elevations_rad.begin(), elevations_rad.end(), elevation_rad, std::greater<>());
  if (it == elevations_rad.begin()) return 0;
  if (it == elevations_rad.end()) return n - 1;
  const int below = static_cast<int>(it - elevations_rad.begin());
  return (elevations_rad[below - 1] - elevation_rad) <= (elevation_rad - elevations_rad[below]) ? below - 1 : below;
}

void BeamLayout::validate(const std::string& where) const {
  if (rows() < 1) throw input_error(where, "elevations", "need at least one beam");
  if (rows() > kMaxRows)
    throw input_error(where, "rows", "at most " + std::to_string(kMaxRows) + ", got " + std::to_string(rows()));
  if (columns < 1 || columns > kMaxColumns)
    throw input_error(where, "columns",
                      "must be in [1, " + std::to_string(kMaxColumns) + "], got " + std::to_string(columns));
  for (int r = 0; r < rows(); ++r) {
    if (!std::isfinite(elevations_rad[r]))
      throw input_error(where, "elevations[" + std::to_string(r) + "]", "must be finite");
    if (r > 0 && !(elevations_rad[r] < elevations_rad[r - 1]))
      throw input_error(where, "elevations[" + std::to_string(r) + "]",
                        "must be strictly below the row above (row 0 is the top beam)");
  }
  if (!azimuth_offsets_rad.empty() && static_cast<int>(azimuth_offsets_rad.size()) != rows())
    throw input_error(where, "azimuth_offsets_deg",
                      "expected one per beam (" + std::to_string(rows()) + "), got " + std::to_string(azimuth_offsets_rad.size()));
  for (double a : azimuth_offsets_rad)
    if (!std::isfinite(a)) throw input_error(where, "azimuth_offsets_deg", "must be finite");
  if (!(min_range_m >= 0) || !(max_range_m >= 0) || (max_range_m > 0 && !(min_range_m < max_range_m)))
    throw input_error(where, "min_range_m/max_range_m", "expected 0 <= min_range_m < max_range_m (0 = not given)");
}

std::string BeamLayout::to_json() const {
  nlohmann::json j;
  j["name"] = name;
  j["columns"] = columns;
  std::vector<double> deg;
  for (double e : elevations_rad) deg.push_back(e / kDeg);
  j["elevations_deg"] = deg;
  if (!azimuth_offsets_rad.empty()) {
    std::vector<double> az;
    for (double a : azimuth_offsets_rad) az.push_back(a / kDeg);
    j["azimuth_offsets_deg"] = az;
  }
  if (min_range_m > 0) j["min_range_m"] = min_range_m;
  if (max_range_m > 0) j["max_range_m"] = max_range_m;
  if (!sensor.empty()) j["sensor"] = sensor;
  return j.dump();
}

BeamLayout BeamLayout::from_json(const std::string& text, const std::string& where) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw input_error(where, "beam layout", std::string("not valid JSON: ") + e.what());
  }
  if (!j.is_object()) throw input_error(where, "beam layout", "expected a JSON object");
  auto get_number = [&](const char* key) {
    if (!j.contains(key) || !j[key].is_number()) throw input_error(where, key, "missing or not a number");
    const double v = j[key].get<double>();
    if (!std::isfinite(v)) throw input_error(where, key, "must be finite");
    return v;
  };
  // Counts are checked as numbers before the cast: a double beyond int's range cast to int is
  // undefined (found by fuzz/ sensor_layout: "columns": 1e29).
  auto get_count = [&](const char* key, int max) {
    const double v = get_number(key);
    if (v < 1 || v > max || v != std::floor(v))
      throw input_error(where, key, "must be a whole number from 1 to " + std::to_string(max));
    return static_cast<int>(v);
  };
  if (j.contains("name") && !j["name"].is_string()) throw input_error(where, "name", "expected a string");
  const std::string name = j.value("name", std::string("custom"));
  const int columns = get_count("columns", kMaxColumns);
  if (j.contains("elevations_deg")) {
    if (!j["elevations_deg"].is_array()) throw input_error(where, "elevations_deg", "expected an array of degrees");
    std::vector<double> deg;
    for (std::size_t i = 0; i < j["elevations_deg"].size(); ++i) {
      const auto& v = j["elevations_deg"][i];
      if (!v.is_number()) throw input_error(where, "elevations_deg[" + std::to_string(i) + "]", "expected a number");
      deg.push_back(v.get<double>());
    }
    BeamLayout layout;
    layout.name = name;
    layout.columns = columns;
    for (double e : deg) layout.elevations_rad.push_back(e * kDeg);
    if (j.contains("azimuth_offsets_deg")) {
      if (!j["azimuth_offsets_deg"].is_array()) throw input_error(where, "azimuth_offsets_deg", "expected an array of degrees");
      for (std::size_t i = 0; i < j["azimuth_offsets_deg"].size(); ++i) {
        const auto& v = j["azimuth_offsets_deg"][i];
        if (!v.is_number()) throw input_error(where, "azimuth_offsets_deg[" + std::to_string(i) + "]", "expected a number");
        layout.azimuth_offsets_rad.push_back(v.get<double>() * kDeg);
      }
    }
    if (j.contains("min_range_m")) layout.min_range_m = get_number("min_range_m");
    if (j.contains("max_range_m")) layout.max_range_m = get_number("max_range_m");
    if (j.contains("sensor")) {
      if (!j["sensor"].is_string()) throw input_error(where, "sensor", "expected a string");
      layout.sensor = j["sensor"].get<std::string>();
    }
    layout.validate(where);
    return layout;
  }
  if (name == "hdl64e" && !j.contains("rows")) return hdl64e(columns);
  const int rows = get_count("rows", kMaxRows);
  BeamLayout layout = uniform(rows, get_number("top_deg"), get_number("bottom_deg"), columns);
  layout.name = name;
  layout.validate(where);
  return layout;
}

BeamLayout BeamLayout::from_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path, "file", "not found or cannot be opened");
  std::stringstream text;
  text << in.rdbuf();
  return from_json(text.str(), path);
}

}  // namespace lidarsim::pgm

namespace lidarsim::pgm {

std::string BeamLayout::difference(const BeamLayout& other) const {
  std::vector<std::string> parts;
  if (name != other.name) parts.push_back("name '" + name + "' vs '" + other.name + "'");
  if (rows() != other.rows())
    parts.push_back("rows " + std::to_string(rows()) + " vs " + std::to_string(other.rows()));
  else if (elevations_rad != other.elevations_rad)
    parts.push_back("row elevations differ");
  if (columns != other.columns)
    parts.push_back("columns " + std::to_string(columns) + " vs " + std::to_string(other.columns));
  std::string out;
  for (const auto& p : parts) out += (out.empty() ? "" : ", ") + p;
  return out;
}

}  // namespace lidarsim::pgm
