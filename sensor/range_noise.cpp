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

const std::vector<std::string>& range_noise_term_features() {
  static const std::vector<std::string> f = {"laser", "range", "class", "material", "azimuth", "incidence", "intensity"};
  return f;
}

double RangeNoiseTerm::factor_at(const RangeNoiseFeatures& f) const {
  double v = 0;
  if (feature == "laser") v = f.row;
  else if (feature == "range") v = f.range_m;
  else if (feature == "class") v = f.class_id;
  else if (feature == "material") v = f.material;
  else if (feature == "azimuth") v = f.azimuth_deg;
  else if (feature == "incidence") v = f.incidence_rad * (180 / std::numbers::pi);
  else if (feature == "intensity") v = f.intensity;
  if (!std::isfinite(v) || factor.empty()) return 1;
  const long n = static_cast<long>(factor.size());
  long k = static_cast<long>(std::floor(v / width));
  k = feature == "azimuth" ? ((k % n) + n) % n : std::clamp(k, 0L, n - 1);
  return factor[static_cast<std::size_t>(k)];
}

double RangeNoiseModel::sigma_at(const RangeNoiseFeatures& f) const {
  double s = sigma(f.range_m);
  if (extra_per_m > 0) s = std::hypot(s, extra_per_m * f.range_m);
  for (const auto& t : terms) s *= t.factor_at(f);
  return s;
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
  if (!std::isfinite(extra_per_m) || extra_per_m < 0 || extra_per_m > 0.1)
    throw input_error(where, "extra_sigma_per_m", "must be in [0, 0.1] m per m, got " + std::to_string(extra_per_m));
  const auto& known = range_noise_term_features();
  for (std::size_t t = 0; t < terms.size(); ++t) {
    const std::string field = "terms[" + std::to_string(t) + "]";
    if (std::find(known.begin(), known.end(), terms[t].feature) == known.end())
      throw input_error(where, field + ".feature", "\"" + terms[t].feature +
                                                       "\" is not one of laser, range, class, material, azimuth, incidence, intensity");
    if (!std::isfinite(terms[t].width) || !(terms[t].width > 0))
      throw input_error(where, field + ".width", "must be > 0, got " + std::to_string(terms[t].width));
    if (terms[t].factor.empty()) throw input_error(where, field + ".factor", "must hold at least one factor");
    for (double v : terms[t].factor)
      if (!std::isfinite(v) || !(v > 0) || v > 100)
        throw input_error(where, field + ".factor", "every factor must be in (0, 100], got " + std::to_string(v));
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
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() < 1 ||
      j["version"].get<int>() > 2)
    throw input_error(file, "version", "expected 1 or 2 (this build reads versions 1 and 2; 2 adds \"terms\")");
  const int version = j["version"].get<int>();
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
  if (j.contains("terms")) {
    if (version < 2) throw input_error(file, "terms", "needs \"version\": 2 (a version-1 file has no terms)");
    if (!j["terms"].is_array()) throw input_error(file, "terms", "must be an array of objects");
    for (std::size_t t = 0; t < j["terms"].size(); ++t) {
      const json& e = j["terms"][t];
      const std::string field = "terms[" + std::to_string(t) + "]";
      if (!e.is_object() || !e.contains("feature") || !e["feature"].is_string())
        throw input_error(file, field + ".feature", "must be a string");
      if (!e.contains("width") || !e["width"].is_number()) throw input_error(file, field + ".width", "must be a number");
      if (!e.contains("factor") || !e["factor"].is_array()) throw input_error(file, field + ".factor", "must be an array of numbers");
      RangeNoiseTerm term;
      term.feature = e["feature"].get<std::string>();
      term.width = e["width"].get<double>();
      for (const auto& v : e["factor"]) {
        if (!v.is_number()) throw input_error(file, field + ".factor", "must be an array of numbers, got " + v.dump());
        term.factor.push_back(v.get<double>());
      }
      term.note = e.value("note", std::string());
      m.terms.push_back(std::move(term));
    }
  }
  if (j.contains("extra_sigma_per_m")) {
    if (version < 2) throw input_error(file, "extra_sigma_per_m", "needs \"version\": 2");
    if (!j["extra_sigma_per_m"].is_number()) throw input_error(file, "extra_sigma_per_m", "must be a number (m per m)");
    m.extra_per_m = j["extra_sigma_per_m"].get<double>();
  }
  m.sensor = j.value("sensor", std::string());
  m.source = j.value("source", std::string());
  m.validate(file);
  return m;
}

std::string range_noise_model_json(const RangeNoiseModel& m) {
  json j;
  j["format"] = "lidarsim-range-noise";
  j["version"] = m.has_terms() ? 2 : 1;
  j["sensor"] = m.sensor;
  j["source"] = m.source;
  j["sigma_m"] = {{"a", m.a}, {"b", m.b}};
  j["table"] = {{"range_m", m.table_range_m}, {"sigma_m", m.table_sigma_m}};
  if (m.extra_per_m > 0) j["extra_sigma_per_m"] = m.extra_per_m;
  if (!m.terms.empty()) {
    j["terms"] = json::array();
    for (const auto& t : m.terms)
      j["terms"].push_back({{"feature", t.feature}, {"width", t.width}, {"factor", t.factor}, {"note", t.note}});
  }
  return j.dump(1) + "\n";
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
  // The channels the terms read (null: not read); a term whose channel is missing is an error.
  const float *cls = nullptr, *mat = nullptr, *inc = nullptr, *inten = nullptr;
  for (const auto& t : model.terms) {
    const char* need = t.feature == "class" ? "class" : t.feature == "material" ? "material" :
                       t.feature == "incidence" ? "incidence" : t.feature == "intensity" ? "intensity" : nullptr;
    if (!need) continue;
    if (!map.has_channel(need))
      throw Error("range noise: the model's " + t.feature + " term needs the map's \"" + need + "\" channel, which it lacks");
    (t.feature == "class" ? cls : t.feature == "material" ? mat : t.feature == "incidence" ? inc : inten) = map.channel(need);
  }
  const int cols = map.cols();
  int moved = 0;
  // One pass on the calling thread: a few nanoseconds per cell, less than waking a thread team on
  // a busy machine.
  for (std::int64_t i = 0; i < cells; ++i) {
    if (!(mask[i] > 0) || !(range[i] > 0)) continue;
    const double r = range[i];
    double sigma = model.sigma(r);
    if (model.has_terms()) {
      RangeNoiseFeatures f;
      f.range_m = r;
      f.row = static_cast<int>(i / cols);
      f.azimuth_deg = 360.0 * (static_cast<double>(i % cols) + 0.5) / cols;
      if (cls) f.class_id = static_cast<int>(cls[i]);
      if (mat) f.material = static_cast<int>(mat[i]);
      if (inc && inc[i] > 0) f.incidence_rad = inc[i];  // 0: not estimated
      if (inten) f.intensity = inten[i];
      sigma = model.sigma_at(f);
    }
    const double noisy = std::max(1e-3, r + sigma * range_noise_normal(seed, frame, static_cast<std::uint64_t>(i)));
    const double scale = noisy / r;
    range[i] = static_cast<float>(noisy);
    for (float* ch : along)
      if (ch) ch[i] = static_cast<float>(ch[i] * scale);
    ++moved;
  }
  return moved;
}

}  // namespace lidarsim::sensor
