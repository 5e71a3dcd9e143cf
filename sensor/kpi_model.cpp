#include "sensor/kpi_model.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"

namespace lidarsim::sensor {

using nlohmann::json;

const char* to_string(KpiParam p) {
  static const char* names[kNumKpiParams] = {"position_along", "position_across", "position_vertical",
                                             "velocity_along", "velocity_across", "length",
                                             "width",          "height",          "heading"};
  return names[static_cast<int>(p)];
}

std::string kpi_class_name(ObjectClass cls) { return to_string(cls); }

double Innovation::excess_kurtosis() const {
  switch (type) {
    case Type::Gaussian: return 0;
    case Type::StudentT: return dof > 4 ? 6 / (dof - 4) : std::numeric_limits<double>::infinity();
    case Type::Mixture: {
      // unit variance: (1-p) s1^2 + p (r s1)^2 = 1
      const double p = outlier_probability, r2 = outlier_scale * outlier_scale;
      const double s1sq = 1 / ((1 - p) + p * r2);
      return 3 * ((1 - p) * s1sq * s1sq + p * r2 * r2 * s1sq * s1sq) - 3;
    }
  }
  return 0;
}

int KpiModel::range_bin(double range) const {
  const auto it = std::upper_bound(range_bin_edges.begin(), range_bin_edges.end(), range);
  return std::max(0, static_cast<int>(it - range_bin_edges.begin()) - 1);
}

int KpiModel::visibility_bin(double v) const {
  const auto it = std::upper_bound(visibility_bin_edges.begin(), visibility_bin_edges.end(), v);
  return std::max(0, static_cast<int>(it - visibility_bin_edges.begin()) - 1);
}

int ConditionalTerm::bin(double value) const {
  const auto it = std::upper_bound(edges.begin(), edges.end(), value);
  return std::max(0, static_cast<int>(it - edges.begin()) - 1);
}

int FalsePositiveTable::bin(double value) const {
  const auto it = std::upper_bound(edges.begin(), edges.end(), value);
  return std::max(0, static_cast<int>(it - edges.begin()) - 1);
}

double FalsePositiveTable::total_rate() const {
  double s = 0;
  for (double r : rate) s += r;
  return s;
}

const ClassModel* KpiModel::find(ObjectClass cls) const {
  auto get = [&](const std::string& name) -> const ClassModel* {
    const auto it = classes.find(name);
    return it == classes.end() ? nullptr : &it->second;
  };
  if (const ClassModel* m = get(kpi_class_name(cls))) return m;
  switch (cls) {
    case ObjectClass::Van:
    case ObjectClass::Truck:
    case ObjectClass::Bus:
    case ObjectClass::Misc: return get("Car");
    case ObjectClass::Motorcycle: return get("Cyclist");
    default: return nullptr;
  }
}

namespace {

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

void check(bool ok, const std::string& file, const std::string& field, const std::string& what, double got) {
  if (!ok) throw input_error(file, field, what + ", got " + num(got));
}

void check_finite(double v, const std::string& file, const std::string& field) {
  check(std::isfinite(v), file, field, "must be a finite number", v);
}

void check_vector(const std::vector<double>& v, size_t n, const std::string& file, const std::string& field,
                  double lo, double hi) {
  if (v.size() != n)
    throw input_error(file, field, "must have " + std::to_string(n) + " entries, got " + std::to_string(v.size()));
  for (size_t i = 0; i < v.size(); ++i) {
    const std::string f = field + "[" + std::to_string(i) + "]";
    check_finite(v[i], file, f);
    check(v[i] >= lo && v[i] <= hi, file, f, "must be in [" + num(lo) + ", " + num(hi) + "]", v[i]);
  }
}

void check_quantiles(const std::vector<double>& q, const std::string& file, const std::string& field) {
  if (q.empty()) return;
  if (q.size() < 2) throw input_error(file, field, "needs at least 2 quantiles (or none)");
  for (size_t i = 0; i < q.size(); ++i) {
    check_finite(q[i], file, field + "[" + std::to_string(i) + "]");
    if (i > 0) check(q[i] >= q[i - 1], file, field + "[" + std::to_string(i) + "]", "must not decrease", q[i]);
  }
}

void check_edges(const std::vector<double>& e, const std::string& file, const std::string& field, double hi) {
  if (e.empty()) throw input_error(file, field, "must list at least one lower bin edge (0)");
  check(e[0] == 0, file, field + "[0]", "must be 0", e[0]);
  for (size_t i = 1; i < e.size(); ++i) {
    check_finite(e[i], file, field + "[" + std::to_string(i) + "]");
    check(e[i] > e[i - 1] && e[i] <= hi, file, field + "[" + std::to_string(i) + "]", "must increase", e[i]);
  }
}

// --- JSON reading with the field path in every message ---

const json& member(const json& j, const char* key, const std::string& file, const std::string& path) {
  if (!j.is_object()) throw input_error(file, path, "must be an object");
  const auto it = j.find(key);
  if (it == j.end()) throw input_error(file, path.empty() ? key : path + "." + key, "missing");
  return *it;
}

double number(const json& j, const std::string& file, const std::string& path) {
  if (!j.is_number()) throw input_error(file, path, "must be a number, got " + j.dump());
  const double v = j.get<double>();
  check_finite(v, file, path);
  return v;
}

double number_at(const json& j, const char* key, const std::string& file, const std::string& path, double fallback,
                 bool optional) {
  if (optional && j.is_object() && !j.contains(key)) return fallback;
  return number(member(j, key, file, path), file, path.empty() ? key : path + "." + key);
}

std::vector<double> numbers(const json& j, const std::string& file, const std::string& path) {
  if (!j.is_array()) throw input_error(file, path, "must be an array of numbers");
  std::vector<double> v;
  for (size_t i = 0; i < j.size(); ++i) v.push_back(number(j[i], file, path + "[" + std::to_string(i) + "]"));
  return v;
}

std::vector<double> numbers_at(const json& j, const char* key, const std::string& file, const std::string& path,
                               bool optional) {
  if (optional && j.is_object() && !j.contains(key)) return {};
  return numbers(member(j, key, file, path), file, path + "." + key);
}

Innovation read_innovation(const json& j, const std::string& file, const std::string& path) {
  Innovation in;
  const json& t = member(j, "type", file, path);
  const std::string type = t.is_string() ? t.get<std::string>() : "";
  if (type == "gaussian") {
    in.type = Innovation::Type::Gaussian;
  } else if (type == "student_t") {
    in.type = Innovation::Type::StudentT;
    in.dof = number_at(j, "dof", file, path, 0, false);
  } else if (type == "mixture") {
    in.type = Innovation::Type::Mixture;
    in.outlier_probability = number_at(j, "outlier_probability", file, path, 0, false);
    in.outlier_scale = number_at(j, "outlier_scale", file, path, 1, false);
  } else {
    throw input_error(file, path + ".type", "must be \"gaussian\", \"student_t\" or \"mixture\", got " + t.dump());
  }
  return in;
}

json write_innovation(const Innovation& in) {
  switch (in.type) {
    case Innovation::Type::Gaussian: return {{"type", "gaussian"}};
    case Innovation::Type::StudentT: return {{"type", "student_t"}, {"dof", in.dof}};
    case Innovation::Type::Mixture:
      return {{"type", "mixture"}, {"outlier_probability", in.outlier_probability}, {"outlier_scale", in.outlier_scale}};
  }
  return {};
}

// A conditional term (absent: nothing to check). On detection the bias is added to a probability
// (so within [-1, 1]) and there is no sigma to scale.
void check_conditional(const ConditionalTerm& ct, const std::string& file, const std::string& cf, bool detection) {
  if (!ct.present()) return;
  if (std::find(kConditionalFeatures.begin(), kConditionalFeatures.end(), ct.feature) == kConditionalFeatures.end()) {
    std::string names;
    for (const auto& n : kConditionalFeatures) names += (names.empty() ? "" : ", ") + n;
    throw input_error(file, cf + ".feature", "must be one of the features the KPI manager computes (" + names +
                                                 "), got \"" + ct.feature + "\"");
  }
  if (ct.edges.empty()) throw input_error(file, cf + ".edges", "must list at least one lower bin edge");
  for (size_t i = 0; i < ct.edges.size(); ++i) {
    const std::string fi = cf + ".edges[" + std::to_string(i) + "]";
    check_finite(ct.edges[i], file, fi);
    if (i > 0) check(ct.edges[i] > ct.edges[i - 1], file, fi, "must increase", ct.edges[i]);
  }
  const double inf = std::numeric_limits<double>::infinity();
  check_vector(ct.bias, ct.edges.size(), file, cf + ".bias", detection ? -1 : -inf, detection ? 1 : inf);
  // A detection term's scale multiplies the cell's probability (a gain), its bias then shifts it.
  if (!ct.scale.empty()) check_vector(ct.scale, ct.edges.size(), file, cf + ".scale", detection ? 0 : 1e-6, inf);
  if (ct.relative_to.empty()) return;
  if (detection)
    throw input_error(file, cf + ".relative_to", "is for error terms only (a detection term's bias is a probability)");
  if (std::find(kConditionalFeatures.begin(), kConditionalFeatures.end(), ct.relative_to) == kConditionalFeatures.end())
    throw input_error(file, cf + ".relative_to",
                      "must be one of the features the KPI manager computes, got \"" + ct.relative_to + "\"");
}

ConditionalTerm read_conditional(const json& j, const std::string& file, const std::string& cf) {
  ConditionalTerm ct;
  const json& fj = member(j, "feature", file, cf);
  if (!fj.is_string() || fj.get<std::string>().empty())
    throw input_error(file, cf + ".feature", "must be a feature name, got " + fj.dump());
  ct.feature = fj.get<std::string>();
  ct.edges = numbers_at(j, "edges", file, cf, false);
  ct.bias = numbers_at(j, "bias", file, cf, false);
  ct.scale = numbers_at(j, "scale", file, cf, true);
  if (j.contains("relative_to")) {
    const json& rj = j["relative_to"];
    if (!rj.is_string() || rj.get<std::string>().empty())
      throw input_error(file, cf + ".relative_to", "must be a feature name, got " + rj.dump());
    ct.relative_to = rj.get<std::string>();
  }
  return ct;
}

json write_conditional(const ConditionalTerm& ct) {
  json j = {{"feature", ct.feature}, {"edges", ct.edges}, {"bias", ct.bias}};
  if (!ct.scale.empty()) j["scale"] = ct.scale;
  if (!ct.relative_to.empty()) j["relative_to"] = ct.relative_to;
  return j;
}

// The false-positive table (absent: nothing to check). A bin with a rate needs range and azimuth
// quantiles, its own or the class's.
void check_fp_table(const ClassModel& c, const std::string& file, const std::string& tf) {
  const FalsePositiveTable& t = c.fp_table;
  if (!t.present()) return;
  if (std::find(kFalsePositiveFeatures.begin(), kFalsePositiveFeatures.end(), t.feature) ==
      kFalsePositiveFeatures.end())
    throw input_error(file, tf + ".feature", "must be range, azimuth or score, got \"" + t.feature + "\"");
  if (t.edges.empty()) throw input_error(file, tf + ".edges", "must list at least one lower bin edge");
  for (size_t i = 0; i < t.edges.size(); ++i) {
    const std::string fi = tf + ".edges[" + std::to_string(i) + "]";
    check_finite(t.edges[i], file, fi);
    if (i > 0) check(t.edges[i] > t.edges[i - 1], file, fi, "must increase", t.edges[i]);
  }
  check_vector(t.rate, t.edges.size(), file, tf + ".rate", 0, 1e6);
  const std::pair<const std::vector<std::vector<double>>*, const char*> qs[3] = {
      {&t.range_quantiles, "range_quantiles"}, {&t.azimuth_quantiles, "azimuth_quantiles"},
      {&t.score_quantiles, "score_quantiles"}};
  for (const auto& [q, name] : qs) {
    if (!q->empty() && q->size() != t.edges.size())
      throw input_error(file, tf + "." + name,
                        "must have " + std::to_string(t.edges.size()) + " entries (one per bin) or none, got " +
                            std::to_string(q->size()));
    for (size_t b = 0; b < q->size(); ++b) check_quantiles((*q)[b], file, tf + "." + name + "[" + std::to_string(b) + "]");
  }
  for (size_t b = 0; b < t.edges.size(); ++b) {
    if (t.rate[b] <= 0) continue;
    const bool range = (!t.range_quantiles.empty() && !t.range_quantiles[b].empty()) || !c.fp_range_quantiles.empty();
    const bool az = (!t.azimuth_quantiles.empty() && !t.azimuth_quantiles[b].empty()) || !c.fp_azimuth_quantiles.empty();
    if (!range || !az)
      throw input_error(file, tf + "." + (range ? "azimuth_quantiles" : "range_quantiles") + "[" + std::to_string(b) + "]",
                        "needed (or the class's) where the bin's rate > 0");
  }
}

FalsePositiveTable read_fp_table(const json& j, const std::string& file, const std::string& tf) {
  FalsePositiveTable t;
  const json& fj = member(j, "feature", file, tf);
  if (!fj.is_string() || fj.get<std::string>().empty())
    throw input_error(file, tf + ".feature", "must be a feature name, got " + fj.dump());
  t.feature = fj.get<std::string>();
  t.edges = numbers_at(j, "edges", file, tf, false);
  t.rate = numbers_at(j, "rate", file, tf, false);
  for (auto [q, name] : {std::pair{&t.range_quantiles, "range_quantiles"}, std::pair{&t.azimuth_quantiles, "azimuth_quantiles"},
                         std::pair{&t.score_quantiles, "score_quantiles"}}) {
    if (!j.contains(name)) continue;
    const json& a = j[name];
    if (!a.is_array()) throw input_error(file, tf + "." + name, "must be an array of quantile arrays");
    for (size_t b = 0; b < a.size(); ++b) q->push_back(numbers(a[b], file, tf + "." + name + "[" + std::to_string(b) + "]"));
  }
  return t;
}

json write_fp_table(const FalsePositiveTable& t) {
  json j = {{"feature", t.feature}, {"edges", t.edges}, {"rate", t.rate}};
  if (!t.range_quantiles.empty()) j["range_quantiles"] = t.range_quantiles;
  if (!t.azimuth_quantiles.empty()) j["azimuth_quantiles"] = t.azimuth_quantiles;
  if (!t.score_quantiles.empty()) j["score_quantiles"] = t.score_quantiles;
  return j;
}

void check_fp_persistence(const FalsePositivePersistence& p, const std::string& file, const std::string& pf) {
  check_finite(p.survival, file, pf + ".survival");
  check(p.survival >= 0 && p.survival <= 0.999, file, pf + ".survival", "must be in [0, 0.999]", p.survival);
  check_finite(p.ghost_share, file, pf + ".ghost_share");
  check(p.ghost_share > 0 && p.ghost_share <= 1, file, pf + ".ghost_share", "must be in (0, 1]", p.ghost_share);
  check_finite(p.jitter, file, pf + ".jitter");
  check(p.jitter >= 0 && p.jitter <= 100, file, pf + ".jitter", "must be in [0, 100] m", p.jitter);
  check_finite(p.score_ar1, file, pf + ".score_ar1");
  check(p.score_ar1 >= 0 && p.score_ar1 <= 1, file, pf + ".score_ar1", "must be in [0, 1]", p.score_ar1);
}

// "survival" is needed (an object without it says nothing); ghost_share defaults to 1, jitter and
// score_ar1 to 0.
FalsePositivePersistence read_fp_persistence(const json& j, const std::string& file, const std::string& pf) {
  if (!j.is_object()) throw input_error(file, pf, "must be an object with survival, ghost_share, jitter, score_ar1");
  FalsePositivePersistence p;
  p.survival = number_at(j, "survival", file, pf, 0, false);
  p.ghost_share = number_at(j, "ghost_share", file, pf, 1, true);
  p.jitter = number_at(j, "jitter", file, pf, 0, true);
  p.score_ar1 = number_at(j, "score_ar1", file, pf, 0, true);
  return p;
}

}  // namespace

void KpiModel::validate(const std::string& file) const {
  check_edges(range_bin_edges, file, "range_bin_edges", 1e4);
  check_edges(visibility_bin_edges, file, "visibility_bin_edges", 1);
  const size_t nr = range_bin_edges.size(), nv = visibility_bin_edges.size();
  const double inf = std::numeric_limits<double>::infinity();
  if (classes.empty()) throw input_error(file, "classes", "must define at least one class");
  for (const auto& [name, c] : classes) {
    const std::string base = "classes." + name;
    for (int p = 0; p < kNumKpiParams; ++p) {
      const ErrorModel& e = c.errors[p];
      const std::string f = base + ".errors." + to_string(static_cast<KpiParam>(p));
      check_vector(e.mean, nr, file, f + ".mean", -inf, inf);
      check_vector(e.sigma, nr, file, f + ".std", 0, inf);
      check_vector(e.visibility_std_scale, nv, file, f + ".visibility_std_scale", 1e-6, inf);
      check_finite(e.ar1, file, f + ".ar1");
      check(e.ar1 > -1 && e.ar1 < 1, file, f + ".ar1", "must be in (-1, 1)", e.ar1);
      check_finite(e.track_std, file, f + ".track_std");
      check(e.track_std >= 0, file, f + ".track_std", "must be >= 0", e.track_std);
      const Innovation& in = e.innovation;
      if (in.type == Innovation::Type::StudentT)
        check(in.dof > 2, file, f + ".innovation.dof", "must be > 2 (finite variance)", in.dof);
      if (in.type == Innovation::Type::Mixture) {
        check(in.outlier_probability > 0 && in.outlier_probability < 1, file, f + ".innovation.outlier_probability",
              "must be in (0, 1)", in.outlier_probability);
        check(in.outlier_scale >= 1, file, f + ".innovation.outlier_scale", "must be >= 1", in.outlier_scale);
      }
      check_conditional(e.conditional, file, f + ".conditional", false);
    }
    if (c.detection_probability.size() != nr)
      throw input_error(file, base + ".detection_probability",
                        "must have " + std::to_string(nr) + " rows (range bins), got " +
                            std::to_string(c.detection_probability.size()));
    for (size_t r = 0; r < nr; ++r)
      check_vector(c.detection_probability[r], nv, file, base + ".detection_probability[" + std::to_string(r) + "]", 0, 1);
    check_conditional(c.detection_conditional, file, base + ".detection_conditional", true);
    check_finite(c.miss_burst_mean, file, base + ".miss_burst_mean");
    check(c.miss_burst_mean >= 1, file, base + ".miss_burst_mean", "must be >= 1 frame", c.miss_burst_mean);
    check_finite(c.heading_flip_probability, file, base + ".heading_flip_probability");
    check(c.heading_flip_probability >= 0 && c.heading_flip_probability < 1, file, base + ".heading_flip_probability",
          "must be in [0, 1)", c.heading_flip_probability);
    check_finite(c.flip_burst_mean, file, base + ".flip_burst_mean");
    check(c.flip_burst_mean >= 1, file, base + ".flip_burst_mean", "must be >= 1 frame", c.flip_burst_mean);
    check_quantiles(c.score_quantiles, file, base + ".score_quantiles");
    check_finite(c.false_positive_rate, file, base + ".false_positive_rate");
    check(c.false_positive_rate >= 0, file, base + ".false_positive_rate", "must be >= 0", c.false_positive_rate);
    check_quantiles(c.fp_range_quantiles, file, base + ".fp_range_quantiles");
    check_quantiles(c.fp_azimuth_quantiles, file, base + ".fp_azimuth_quantiles");
    check_quantiles(c.fp_score_quantiles, file, base + ".fp_score_quantiles");
    if (c.false_positive_rate > 0 && (c.fp_range_quantiles.empty() || c.fp_azimuth_quantiles.empty()))
      throw input_error(file, base + ".fp_range_quantiles", "needed when false_positive_rate > 0");
    check_finite(c.fp_z, file, base + ".fp_z");
    check_fp_table(c, file, base + ".fp_table");
    check_fp_persistence(c.fp_persistence, file, base + ".fp_persistence");
    for (int i = 0; i < 3; ++i) {
      const std::string f = base + ".mean_size[" + std::to_string(i) + "]";
      check_finite(c.mean_size[i], file, f);
      check(c.mean_size[i] > 0, file, f, "must be positive", c.mean_size[i]);
    }
  }
  const std::string cf = "controller";
  check(std::isfinite(controller.window) && controller.window >= 1, file, cf + ".window", "must be >= 1", controller.window);
  check(std::isfinite(controller.mean_gain) && controller.mean_gain >= 0 && controller.mean_gain < 1, file,
        cf + ".mean_gain", "must be in [0, 1)", controller.mean_gain);
  check(std::isfinite(controller.std_gain) && controller.std_gain >= 0 && controller.std_gain < 1, file,
        cf + ".std_gain", "must be in [0, 1)", controller.std_gain);
}

KpiModel parse_kpi_model(const std::string& text, const std::string& file) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {  // syntax errors, and numbers that overflow to +-inf
    throw input_error(file, "(document)", std::string("not valid JSON: ") + e.what());
  }
  KpiModel m;
  const json& fmt = member(j, "format", file, "");
  if (fmt != "lidarsim-kpi-model")
    throw input_error(file, "format", "must be \"lidarsim-kpi-model\", got " + fmt.dump());
  if (j.contains("source")) {
    if (!j["source"].is_string()) throw input_error(file, "source", "must be a string, got " + j["source"].dump());
    m.source = j["source"].get<std::string>();
  }
  m.range_bin_edges = numbers_at(j, "range_bin_edges", file, "", false);
  m.visibility_bin_edges = numbers_at(j, "visibility_bin_edges", file, "", false);
  const size_t nv = m.visibility_bin_edges.size();
  const json& classes = member(j, "classes", file, "");
  if (!classes.is_object()) throw input_error(file, "classes", "must be an object of class models");
  for (const auto& [name, cj] : classes.items()) {
    ClassModel c;
    const std::string base = "classes." + name;
    const json& errors = member(cj, "errors", file, base);
    for (int p = 0; p < kNumKpiParams; ++p) {
      const std::string pn = to_string(static_cast<KpiParam>(p));
      const std::string f = base + ".errors." + pn;
      const json& ej = member(errors, pn.c_str(), file, base + ".errors");
      ErrorModel& e = c.errors[p];
      e.mean = numbers_at(ej, "mean", file, f, false);
      e.sigma = numbers_at(ej, "std", file, f, false);
      e.visibility_std_scale = numbers_at(ej, "visibility_std_scale", file, f, true);
      if (e.visibility_std_scale.empty()) e.visibility_std_scale.assign(nv, 1.0);
      e.ar1 = number_at(ej, "ar1", file, f, 0, false);
      e.track_std = number_at(ej, "track_std", file, f, 0, true);
      e.innovation = ej.contains("innovation") ? read_innovation(ej["innovation"], file, f + ".innovation") : Innovation{};
      if (ej.contains("conditional")) e.conditional = read_conditional(ej["conditional"], file, f + ".conditional");
    }
    const json& dp = member(cj, "detection_probability", file, base);
    if (!dp.is_array()) throw input_error(file, base + ".detection_probability", "must be an array of arrays");
    for (size_t r = 0; r < dp.size(); ++r)
      c.detection_probability.push_back(numbers(dp[r], file, base + ".detection_probability[" + std::to_string(r) + "]"));
    if (cj.contains("detection_conditional"))
      c.detection_conditional = read_conditional(cj["detection_conditional"], file, base + ".detection_conditional");
    c.miss_burst_mean = number_at(cj, "miss_burst_mean", file, base, 1, true);
    c.heading_flip_probability = number_at(cj, "heading_flip_probability", file, base, 0, true);
    c.flip_burst_mean = number_at(cj, "flip_burst_mean", file, base, 1, true);
    c.score_quantiles = numbers_at(cj, "score_quantiles", file, base, true);
    c.false_positive_rate = number_at(cj, "false_positive_rate", file, base, 0, true);
    c.fp_range_quantiles = numbers_at(cj, "fp_range_quantiles", file, base, true);
    c.fp_azimuth_quantiles = numbers_at(cj, "fp_azimuth_quantiles", file, base, true);
    c.fp_score_quantiles = numbers_at(cj, "fp_score_quantiles", file, base, true);
    c.fp_z = number_at(cj, "fp_z", file, base, -0.9, true);
    if (cj.contains("fp_table")) c.fp_table = read_fp_table(cj["fp_table"], file, base + ".fp_table");
    if (cj.contains("fp_persistence"))
      c.fp_persistence = read_fp_persistence(cj["fp_persistence"], file, base + ".fp_persistence");
    if (cj.contains("mean_size")) {
      const auto s = numbers_at(cj, "mean_size", file, base, false);
      if (s.size() != 3) throw input_error(file, base + ".mean_size", "must have 3 entries (length, width, height)");
      c.mean_size = Eigen::Vector3d(s[0], s[1], s[2]);
    }
    m.classes[name] = std::move(c);
  }
  if (j.contains("controller")) {
    const json& cj = j["controller"];
    if (!cj.is_object()) throw input_error(file, "controller", "must be an object, got " + cj.dump());
    if (cj.contains("enabled")) {
      if (!cj["enabled"].is_boolean()) throw input_error(file, "controller.enabled", "must be true or false");
      m.controller.enabled = cj["enabled"].get<bool>();
    }
    m.controller.window = number_at(cj, "window", file, "controller", m.controller.window, true);
    m.controller.mean_gain = number_at(cj, "mean_gain", file, "controller", m.controller.mean_gain, true);
    m.controller.std_gain = number_at(cj, "std_gain", file, "controller", m.controller.std_gain, true);
  }
  m.validate(file);
  return m;
}

KpiModel load_kpi_model(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "(file)", "cannot open the KPI model file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_kpi_model(ss.str(), path.string());
}

std::string kpi_model_to_json(const KpiModel& m) {
  json j;
  j["format"] = "lidarsim-kpi-model";
  j["version"] = 1;
  j["source"] = m.source;
  j["range_bin_edges"] = m.range_bin_edges;
  j["visibility_bin_edges"] = m.visibility_bin_edges;
  j["classes"] = json::object();
  for (const auto& [name, c] : m.classes) {
    json cj;
    for (int p = 0; p < kNumKpiParams; ++p) {
      const ErrorModel& e = c.errors[p];
      cj["errors"][to_string(static_cast<KpiParam>(p))] = {
          {"mean", e.mean}, {"std", e.sigma}, {"visibility_std_scale", e.visibility_std_scale},
          {"ar1", e.ar1}, {"track_std", e.track_std}, {"innovation", write_innovation(e.innovation)}};
      if (e.conditional.present())  // absent: a model without the term writes no key for it
        cj["errors"][to_string(static_cast<KpiParam>(p))]["conditional"] = write_conditional(e.conditional);
    }
    cj["detection_probability"] = c.detection_probability;
    if (c.detection_conditional.present()) cj["detection_conditional"] = write_conditional(c.detection_conditional);
    cj["miss_burst_mean"] = c.miss_burst_mean;
    cj["heading_flip_probability"] = c.heading_flip_probability;
    cj["flip_burst_mean"] = c.flip_burst_mean;
    cj["score_quantiles"] = c.score_quantiles;
    cj["false_positive_rate"] = c.false_positive_rate;
    cj["fp_range_quantiles"] = c.fp_range_quantiles;
    cj["fp_azimuth_quantiles"] = c.fp_azimuth_quantiles;
    cj["fp_score_quantiles"] = c.fp_score_quantiles;
    cj["fp_z"] = c.fp_z;
    if (c.fp_table.present()) cj["fp_table"] = write_fp_table(c.fp_table);  // absent: no key
    if (c.fp_persistence.present())
      cj["fp_persistence"] = {{"survival", c.fp_persistence.survival},
                              {"ghost_share", c.fp_persistence.ghost_share},
                              {"jitter", c.fp_persistence.jitter},
                              {"score_ar1", c.fp_persistence.score_ar1}};
    cj["mean_size"] = {c.mean_size[0], c.mean_size[1], c.mean_size[2]};
    j["classes"][name] = cj;
  }
  j["controller"] = {{"enabled", m.controller.enabled},
                     {"window", m.controller.window},
                     {"mean_gain", m.controller.mean_gain},
                     {"std_gain", m.controller.std_gain}};
  return j.dump(1) + "\n";
}

void save_kpi_model(const KpiModel& model, const std::filesystem::path& path) {
  model.validate(path.string());
  write_file_atomically(path, kpi_model_to_json(model));
}

KpiModel default_kpi_model() {
  KpiModel m;
  m.source = "hand-set default (not calibrated)";
  m.range_bin_edges = {0, 20, 40, 60};
  m.visibility_bin_edges = {0, 0.4, 0.8};
  const int nr = 4, nv = 3;
  auto make = [&](double pos_std, Eigen::Vector3d size, double pd_near, double fp_rate) {
    ClassModel c;
    for (int p = 0; p < kNumKpiParams; ++p) {
      ErrorModel& e = c.errors[p];
      e.mean.assign(nr, 0.0);
      e.sigma.assign(nr, pos_std);
      e.visibility_std_scale = {1.5, 1.2, 1.0};
      e.ar1 = 0.6;
      e.innovation = {Innovation::Type::StudentT, 5, 0, 1};
    }
    c.errors[int(KpiParam::VelocityAlong)].sigma.assign(nr, 0.5);
    c.errors[int(KpiParam::VelocityAcross)].sigma.assign(nr, 0.5);
    c.errors[int(KpiParam::Heading)].sigma.assign(nr, 0.05);
    for (int p : {int(KpiParam::Length), int(KpiParam::Width), int(KpiParam::Height)}) {
      c.errors[p].sigma.assign(nr, 0.03);
      c.errors[p].track_std = 0.1;
    }
    for (int r = 0; r < nr; ++r) {
      const double pr = pd_near * (1 - 0.1 * r);
      c.detection_probability.push_back({0.3 * pr, 0.7 * pr, pr});
    }
    c.miss_burst_mean = 3;
    c.heading_flip_probability = 0.02;
    c.flip_burst_mean = 3;
    c.score_quantiles = {0, 5, 10};
    c.false_positive_rate = fp_rate;
    c.fp_range_quantiles = {5, 20, 60};
    c.fp_azimuth_quantiles = {-0.7, 0, 0.7};
    c.fp_score_quantiles = {0, 1, 5};
    c.mean_size = size;
    return c;
  };
  (void)nv;
  m.classes["Car"] = make(0.15, {4.0, 1.7, 1.5}, 0.95, 0.3);
  m.classes["Pedestrian"] = make(0.1, {0.8, 0.6, 1.75}, 0.85, 0.3);
  m.classes["Cyclist"] = make(0.12, {1.8, 0.6, 1.7}, 0.85, 0.1);
  return m;
}

}  // namespace lidarsim::sensor
