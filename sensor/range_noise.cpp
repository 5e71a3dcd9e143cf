#include "sensor/range_noise.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>

#include "common/counter_hash.h"
#include "common/error.h"

namespace lidarsim::sensor {

using json = nlohmann::json;

double RangeNoiseModel::sigma(double range_m) const {
  auto smooth = [&](double r) { return std::sqrt(a * a + (b * r) * (b * r)); };
  const std::size_t n = table_range_m.size();
  if (n == 0) return smooth(range_m);
  if (range_m <= table_range_m.front()) return table_sigma_m.front();
  if (range_m >= table_range_m.back()) {
    const double at_last = smooth(table_range_m.back());
    return at_last > 0 ? table_sigma_m.back() * smooth(range_m) / at_last : table_sigma_m.back();
  }
  const std::size_t i = std::upper_bound(table_range_m.begin(), table_range_m.end(), range_m) - table_range_m.begin();
  const double t = (range_m - table_range_m[i - 1]) / (table_range_m[i] - table_range_m[i - 1]);
  return table_sigma_m[i - 1] + t * (table_sigma_m[i] - table_sigma_m[i - 1]);
}

void RangeNoiseModel::validate(const std::string& where) const {
  // A spread of a metre at the floor or of 10 % of the range is no range noise: a unit mix-up.
  if (!std::isfinite(a) || a < 0 || a > 1) throw input_error(where, "sigma_m.a", "must be in [0, 1] m, got " + std::to_string(a));
  if (!std::isfinite(b) || b < 0 || b > 0.1)
    throw input_error(where, "sigma_m.b", "must be in [0, 0.1] m per m, got " + std::to_string(b));
  if (table_range_m.size() != table_sigma_m.size())
    throw input_error(where, "table", std::to_string(table_range_m.size()) + " ranges for " +
                                          std::to_string(table_sigma_m.size()) + " spreads");
  for (std::size_t i = 0; i < table_range_m.size(); ++i) {
    if (!std::isfinite(table_range_m[i]) || table_range_m[i] < 0 || (i > 0 && !(table_range_m[i] > table_range_m[i - 1])))
      throw input_error(where, "table.range_m[" + std::to_string(i) + "]", "ranges must be >= 0 and increasing");
    if (!std::isfinite(table_sigma_m[i]) || table_sigma_m[i] < 0 || table_sigma_m[i] > 1)
      throw input_error(where, "table.sigma_m[" + std::to_string(i) + "]",
                        "must be in [0, 1] m, got " + std::to_string(table_sigma_m[i]));
  }
}

RangeNoiseModel parse_range_noise_model(const std::string& text, const std::string& file) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    throw input_error(file, "(json)", e.what());
  }
  if (!j.is_object()) throw input_error(file, "(json)", "must be an object");
  if (j.value("format", std::string()) != "lidarsim-range-noise")
    throw input_error(file, "format", "expected \"lidarsim-range-noise\"");
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() != 1)
    throw input_error(file, "version", "expected 1 (this build reads version 1)");
  if (!j.contains("sigma_m") || !j["sigma_m"].is_object()) throw input_error(file, "sigma_m", "missing (an object with a and b)");
  RangeNoiseModel m;
  for (const char* key : {"a", "b"}) {
    const json& v = j["sigma_m"].contains(key) ? j["sigma_m"][key] : json();
    if (!v.is_number())
      throw input_error(file, std::string("sigma_m.") + key, key[0] == 'a' ? "must be a number (m)" : "must be a number (m per m)");
    (key[0] == 'a' ? m.a : m.b) = v.get<double>();
  }
  if (j.contains("table")) {
    const json& t = j["table"];
    for (const char* key : {"range_m", "sigma_m"}) {
      if (!t.is_object() || !t.contains(key) || !t[key].is_array())
        throw input_error(file, std::string("table.") + key, "must be an array of numbers");
      for (const auto& v : t[key])
        if (!v.is_number()) throw input_error(file, std::string("table.") + key, "must be an array of numbers, got " + v.dump());
    }
    m.table_range_m = t["range_m"].get<std::vector<double>>();
    m.table_sigma_m = t["sigma_m"].get<std::vector<double>>();
  }
  m.sensor = j.value("sensor", std::string());
  m.source = j.value("source", std::string());
  m.validate(file);
  return m;
}

RangeNoiseModel load_range_noise_model(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "(file)", "cannot open the range noise model");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_range_noise_model(ss.str(), path.string());
}

double range_noise_normal(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell) {
  std::uint64_t h = mix64(seed + kSplitMixGamma);
  h = mix64(h ^ (frame + 2 * kSplitMixGamma));
  h = mix64(h ^ (cell + 3 * kSplitMixGamma));
  const std::uint64_t h2 = mix64(h + kSplitMixGamma);
  // Two uniforms from the top 53 bits; u1 in (0, 1] so the log is finite.
  const double u1 = (static_cast<double>(h >> 11) + 1) * 0x1p-53;
  const double u2 = static_cast<double>(h2 >> 11) * 0x1p-53;
  return std::sqrt(-2 * std::log(u1)) * std::cos(2 * std::numbers::pi * u2);
}

int apply_range_noise(const RangeNoiseModel& model, std::uint64_t seed, std::uint64_t frame, pgm::PolarGridMap& map) {
  float* range = map.channel("range");
  const float* mask = map.channel("mask");
  auto optional = [&](const char* n) { return map.has_channel(n) ? map.channel(n) : nullptr; };
  float* along[] = {optional("x"), optional("y"), optional("z"), optional("height")};
  const std::int64_t cells = static_cast<std::int64_t>(map.cells());
  int moved = 0;
  // One pass on the calling thread: a few nanoseconds per cell, less than waking a thread team on
  // a busy machine.
  for (std::int64_t i = 0; i < cells; ++i) {
    if (!(mask[i] > 0) || !(range[i] > 0)) continue;
    const double r = range[i];
    const double noisy = std::max(1e-3, r + model.sigma(r) * range_noise_normal(seed, frame, static_cast<std::uint64_t>(i)));
    const double scale = noisy / r;
    range[i] = static_cast<float>(noisy);
    for (float* ch : along)
      if (ch) ch[i] = static_cast<float>(ch[i] * scale);
    ++moved;
  }
  return moved;
}

}  // namespace lidarsim::sensor
