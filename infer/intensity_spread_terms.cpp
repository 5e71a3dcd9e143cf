// Terms on the spread of sampled intensity: the file and the factor at a cell
// (intensity_spread_terms.h).
#include "infer/intensity_spread_terms.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/error.h"

namespace lidarsim::infer {

namespace {

constexpr const char* kSpreadTermsFormat = "lidarsim-intensity-spread-terms";

const float* term_channel(const pgm::PolarGridMap& map, const std::string& feature) {
  const char* need = feature == "class" ? "class" : feature == "material" ? "material" : feature == "incidence" ? "incidence" : nullptr;
  if (!need) return nullptr;
  if (!map.has_channel(need))
    throw Error("intensity spread terms: the " + feature + " term needs the map's \"" + need + "\" channel, which it lacks");
  return map.channel(need);
}

}  // namespace

IntensitySpreadTerms parse_intensity_spread_terms(const std::string& json_text, const std::string& file) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(json_text);
  } catch (const nlohmann::json::exception& e) {
    throw input_error(file, "(file)", std::string("not JSON: ") + e.what());
  }
  if (!j.is_object() || j.value("format", "") != kSpreadTermsFormat)
    throw input_error(file, "format", std::string("expected \"") + kSpreadTermsFormat + "\"");
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() != 1)
    throw input_error(file, "version", "expected 1 (this build reads version 1)");
  if (!j.contains("terms") || !j["terms"].is_array()) throw input_error(file, "terms", "must be an array of objects");
  IntensitySpreadTerms out;
  out.source = j.value("source", std::string());
  const auto& known = sensor::range_noise_term_features();
  for (std::size_t t = 0; t < j["terms"].size(); ++t) {
    const auto& e = j["terms"][t];
    const std::string field = "terms[" + std::to_string(t) + "]";
    if (!e.is_object() || !e.contains("feature") || !e["feature"].is_string())
      throw input_error(file, field + ".feature", "must be a string");
    sensor::RangeNoiseTerm term;
    term.feature = e["feature"].get<std::string>();
    if (std::find(known.begin(), known.end(), term.feature) == known.end())
      throw input_error(file, field + ".feature", "\"" + term.feature + "\" is not one of laser, range, class, material, azimuth, incidence, intensity");
    if (!e.contains("width") || !e["width"].is_number() || !(e["width"].get<double>() > 0) || !std::isfinite(e["width"].get<double>()))
      throw input_error(file, field + ".width", "must be a number > 0");
    term.width = e["width"].get<double>();
    if (!e.contains("factor") || !e["factor"].is_array() || e["factor"].empty())
      throw input_error(file, field + ".factor", "must be a non-empty array of numbers > 0");
    for (const auto& v : e["factor"]) {
      if (!v.is_number() || !(v.get<double>() > 0) || !std::isfinite(v.get<double>()))
        throw input_error(file, field + ".factor", "must be a non-empty array of numbers > 0");
      term.factor.push_back(v.get<double>());
    }
    term.note = e.value("note", std::string());
    out.terms.push_back(std::move(term));
  }
  return out;
}

IntensitySpreadTerms load_intensity_spread_terms(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "(file)", "cannot be read");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_intensity_spread_terms(ss.str(), path.string());
}

std::string intensity_spread_terms_json(const IntensitySpreadTerms& t) {
  nlohmann::json j = {{"format", kSpreadTermsFormat}, {"version", 1}, {"source", t.source}, {"terms", nlohmann::json::array()}};
  for (const auto& x : t.terms)
    j["terms"].push_back({{"feature", x.feature}, {"width", x.width}, {"factor", x.factor}, {"note", x.note}});
  return j.dump(2) + "\n";
}

SpreadTermFactor::SpreadTermFactor(const std::vector<sensor::RangeNoiseTerm>& terms, const pgm::PolarGridMap& map)
    : terms_(terms), map_(map), range_(map.channel("range")) {
  for (const auto& t : terms)
    if (const float* ch = term_channel(map, t.feature))
      (t.feature == "class" ? cls_ : t.feature == "material" ? material_ : incidence_) = ch;
}

double SpreadTermFactor::at(std::size_t cell, double mean) const {
  if (terms_.empty()) return 1;
  sensor::RangeNoiseFeatures f;
  f.range_m = range_[cell];
  f.row = static_cast<int>(cell / map_.cols());
  f.azimuth_deg = 360.0 * (static_cast<double>(cell % map_.cols()) + 0.5) / map_.cols();
  f.intensity = mean;
  if (cls_) f.class_id = static_cast<int>(cls_[cell]);
  if (material_) f.material = static_cast<int>(material_[cell]);
  if (incidence_ && incidence_[cell] > 0) f.incidence_rad = incidence_[cell];  // 0: not estimated
  double factor = 1;
  for (const auto& t : terms_) factor *= t.factor_at(f);
  return factor;
}

}  // namespace lidarsim::infer
