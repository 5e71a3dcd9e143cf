#pragma once
// The objects half of the campaign of random planted effects, shared by
// bench_loop_campaign_objects and its smoke test (tests/qualify/test_campaign_objects.cpp).
// One draw: plan and write a planted set (data/planted_tracking.h), run `lidar-qualify loop
// objects` blind on it (qualify::loop_objects with the command's default options), score it:
//   recalled   the planted feature is named among the added effects, on the planted target, and
//              that effect's held-out error after <= 0.7 x before;
//   absorbed   the planted feature's candidate on the planted target, in the planted form (a
//              rate for a dropout, a spread form for a spread), is "not ranked: the base KPI model
//              already conditions ..." : the KPI model, fitted to the data before the loop starts,
//              holds the effect (a dropout beyond a range is the detection rate's range bins), so
//              there is nothing to add. Counted apart from recall: the table shows both.
//   other add  anything added that is not the planted effect (on a control: a false add).
//   where planted  (detection dropouts) recalled with the held-out error read only on the objects
//              the planted dropout acts on (inside its azimuth window, beyond its range): a 0/1
//              outcome's noise over every other object, which no term can lower, dilutes the
//              strict figure (the ideal refit reaches 0.7 x over all objects in 2 and 4 of 10
//              draws), while on the objects it acts on a term that misses the effect leaves the
//              error where it was. Other families: the strict rule. Reported beside it.
//   above floor  recalled with the floor removed: the data's own noise (the ideal refit's error,
//              data/planted_tracking.h PlantedStats::ideal_after) is taken out of both errors,
//              sqrt(after^2 - floor^2) <= 0.7 x sqrt(before^2 - floor^2), as the intensity half
//              scores excess error over its noise. Where no ideal exists (spread, fp_cell): recalled.
//   truth      (the headline) the planted feature named on the planted target AND the refitted
//              model's error against the hidden generating model (truth_score below) after <= 0.7 x
//              before, on the held-out objects the loop judged the term on: predicted minus true mean
//              error (bias targets), predicted minus true detection probability (dropouts), log of
//              predicted over true sigma (spread). Outcome noise no model can remove (a 0/1
//              detection's Bernoulli draw, each error's Gaussian draw) is not in it, so it measures
//              the model, not the dice, as the intensity half scores against its noise-free truth.
//              False-positive cells: the loop's own rate error, which already takes the measured
//              counts' Poisson noise out (object_false_positives.h fp_rate_error).
// Everything added is read from the loop's JSON: "added_effects" (bias terms: feature, target,
// before, after), the spread form ("added_kind" spread_*, "effect".target, "before", "after"), the
// false positives' table ("false_positives"."added": feature, error_before, error_after) and their
// persistence ("false_positives"."persistence"."added").
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/angles.h"
#include "data/planted_tracking.h"
#include "qualify/objects/object_loop.h"
#include "qualify/objects/objects.h"

namespace lidarsim::bench {

inline constexpr double kRecallRatio = 0.7;  // held-out error after / before for a recall

struct AddedEffect {
  std::string feature, target, kind;
  double before = std::numeric_limits<double>::quiet_NaN(), after = std::numeric_limits<double>::quiet_NaN();
};

inline double number_or_nan(const nlohmann::json& j, const char* key) {
  return j.contains(key) && j[key].is_number() ? j[key].get<double>() : std::numeric_limits<double>::quiet_NaN();
}

// Everything the loop added, from its report.
inline std::vector<AddedEffect> loop_added_effects(const nlohmann::json& j) {
  std::vector<AddedEffect> out;
  if (j.contains("added_effects"))
    for (const auto& e : j["added_effects"])
      out.push_back({e.value("feature", ""), e.value("target", ""), e.value("kind", ""), number_or_nan(e, "before"),
                     number_or_nan(e, "after")});
  const std::string kind = j.contains("added_kind") && j["added_kind"].is_string() ? j["added_kind"].get<std::string>() : "";
  if (kind.rfind("spread", 0) == 0 && j.contains("effect"))
    out.push_back({j["effect"].value("feature", ""), j["effect"].value("target", ""), kind, number_or_nan(j, "before"),
                   number_or_nan(j, "after")});
  if (j.contains("false_positives")) {
    const auto& fp = j["false_positives"];
    if (fp.contains("added") && fp["added"].is_object())
      out.push_back({fp["added"].value("feature", ""), data::kFalsePositivesTarget, fp["added"].value("kind", ""),
                     number_or_nan(fp["added"], "error_before"), number_or_nan(fp["added"], "error_after")});
    if (fp.contains("persistence") && fp["persistence"].value("added", false))
      out.push_back({"previous_frame", data::kFalsePositivesTarget, "fp_persistence",
                     number_or_nan(fp["persistence"], "error_before"), number_or_nan(fp["persistence"], "error_after")});
  }
  return out;
}

struct DrawScore {
  bool named = false;      // the planted feature added on the planted target
  bool recalled = false;   // named and after <= kRecallRatio x before
  bool above_floor = false;  // named and the excess over the data's noise floor cut as much (see above)
  bool other_add = false;  // something else added (on a control: a false add)
  bool absorbed = false;   // the base KPI model holds the planted form already (see above)
  bool where_recalled = false;  // recalled on the objects the planted effect acts on (see above)
  double where_before = std::numeric_limits<double>::quiet_NaN(), where_after = std::numeric_limits<double>::quiet_NaN();
  long where_objects = 0;  // held-out objects the planted dropout acts on
  double before = std::numeric_limits<double>::quiet_NaN(), after = std::numeric_limits<double>::quiet_NaN();
  nlohmann::json candidates = nlohmann::json::array();  // the planted feature x target's, with decisions
  // Against the hidden truth (truth_score): the starting model's error and the refitted model's.
  bool truth_recalled = false;
  double truth_before = std::numeric_limits<double>::quiet_NaN(), truth_after = std::numeric_limits<double>::quiet_NaN();
  long truth_objects = 0;
};

// The 0.7 rule on the error above the noise floor an ideal refit leaves.
inline bool recalled_above_floor(const DrawScore& s, double floor) {
  if (!s.named) return false;
  if (std::isnan(floor)) return s.recalled;
  auto excess = [floor](double e) { return std::sqrt(std::max(0.0, e * e - floor * floor)); };
  return excess(s.after) <= kRecallRatio * excess(s.before);
}

inline bool names_planted(const data::PlantedEffect& e, const AddedEffect& a) {
  if (e.feature.empty() || a.target != e.target) return false;
  for (const std::string& f : e.features)
    if (a.feature == f) return true;
  return false;
}

// The planted feature x target's candidates (fp_cell: of the false positives' candidates), each
// with its form, score and the loop's decision, best score first.
inline nlohmann::json planted_candidates(const data::PlantedEffect& e, const nlohmann::json& j) {
  const bool fp = e.target == data::kFalsePositivesTarget;
  const nlohmann::json* list = nullptr;
  if (fp && j.contains("false_positives") && j["false_positives"].contains("candidates"))
    list = &j["false_positives"]["candidates"];
  else if (!fp && j.contains("candidates"))
    list = &j["candidates"];
  std::vector<nlohmann::json> found;
  if (list)
    for (const auto& c : *list) {
      if (!fp && c.value("target", "") != e.target) continue;
      if (std::find(e.features.begin(), e.features.end(), c.value("feature", "")) == e.features.end()) continue;
      nlohmann::json k;
      for (const char* key : {"feature", "target", "kind", "score", "interval95", "error_before", "error_after", "decision"})
        if (c.contains(key)) k[key] = c[key];
      found.push_back(k);
    }
  std::sort(found.begin(), found.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    return number_or_nan(a, "score") > number_or_nan(b, "score");
  });
  return found;
}

inline DrawScore score_draw(const data::PlantedEffect& e, const nlohmann::json& j) {
  DrawScore s;
  for (const AddedEffect& a : loop_added_effects(j)) {
    if (names_planted(e, a) && !s.named) {
      s.named = true, s.before = a.before, s.after = a.after;
      s.recalled = a.after <= kRecallRatio * a.before;
    } else {
      s.other_add = true;
    }
  }
  if (!e.feature.empty()) s.candidates = planted_candidates(e, j);
  const bool spread = e.family == data::PlantedFamily::Spread;
  for (const auto& c : s.candidates) {
    const std::string kind = c.value("kind", ""), decision = c.value("decision", "");
    const bool spread_form = kind.rfind("spread", 0) == 0;
    if (spread_form == spread && decision.rfind("not ranked: the base KPI model already conditions", 0) == 0)
      s.absorbed = !s.other_add;
  }
  return s;
}

// Whether candidate c of the loop's result names the planted feature on the planted target.
inline bool names_planted(const data::PlantedEffect& e, const qualify::obj::Candidate& c) {
  return qualify::kObjectTargets[c.target] == e.target &&
         std::find(e.features.begin(), e.features.end(), qualify::kObjectFeatures[c.feature]) != e.features.end();
}

// Whether the planted detection dropout acts on an object with these loop features (kObjectFeatures).
inline bool planted_acts_on(const data::PlantedDraw& d, const std::vector<double>& f) {
  const auto& p = d.effect.params;
  if (d.effect.family == data::PlantedFamily::AzimuthDropout) {
    const double az = f[qualify::obj::feature_index("azimuth")];
    return az >= p.at("azimuth_lo_deg") * kDeg && az <= p.at("azimuth_hi_deg") * kDeg;
  }
  if (d.effect.family == data::PlantedFamily::RangeDropout)
    return f[qualify::obj::feature_index("range")] >= p.at("range_m");
  return false;
}

// The "where planted" figure (see above) from the loop's typed result: the added term that names
// the planted dropout, its held-out RMS residual before and after on the objects the dropout acts
// on. Other families keep the strict rule.
inline void score_where_planted(const data::PlantedDraw& d, const qualify::obj::ObjectLoopResult& R, DrawScore& s) {
  s.where_recalled = s.recalled;
  const bool dropout = d.effect.family == data::PlantedFamily::AzimuthDropout ||
                       d.effect.family == data::PlantedFamily::RangeDropout;
  if (!dropout || !s.named) return;
  for (const qualify::obj::AddedBias& a : R.added) {
    if (!names_planted(d.effect, R.candidates[a.candidate])) continue;  // dropouts: the detection target
    const qualify::obj::Judged& J = a.judged;
    double b = 0, f = 0;
    long n = 0;
    for (size_t i = 0; i < J.held_features.size(); ++i)
      if (planted_acts_on(d, J.held_features[i])) b += J.before_r[i] * J.before_r[i], f += J.after_r[i] * J.after_r[i], ++n;
    s.where_objects = n;
    if (n == 0) return;
    s.where_before = std::sqrt(b / n), s.where_after = std::sqrt(f / n);
    s.where_recalled = s.where_after <= kRecallRatio * s.where_before;
    return;
  }
}

// The loop's object features (kObjectFeatures order) as the generator's description of an object.
inline data::PlantedObject planted_object(const std::vector<double>& f, int cls) {
  using qualify::obj::feature_index;
  data::PlantedObject o;
  o.cls = cls;
  o.range = f[feature_index("range")], o.azimuth = f[feature_index("azimuth")];
  o.radial_velocity = f[feature_index("radial_velocity")], o.speed = f[feature_index("speed")];
  o.aspect = f[feature_index("heading_to_line_of_sight")] / (kPi / 2);
  o.occlusion = f[feature_index("occlusion")], o.truncation = f[feature_index("truncation")];
  o.length = f[feature_index("size")], o.width = f[feature_index("box_width")];
  return o;
}

struct TruthError {
  double before = std::numeric_limits<double>::quiet_NaN(), after = std::numeric_limits<double>::quiet_NaN();
  long objects = 0;
};

// A bias form's error against the truth on its held-out records: the model's prediction is the
// outcome minus its residual (y - r), the truth the generator's mean error of the target (or its
// detection probability); RMS of prediction minus truth with the starting model's residuals
// (before) and the refitted model's (after). Records of other classes are left out.
inline TruthError truth_error(const data::PlantedDraw& d, int target, const std::vector<double>& y,
                              const std::vector<double>& before_r, const std::vector<double>& after_r,
                              const std::vector<std::vector<double>>& features, const std::vector<int>& cls) {
  double b = 0, a = 0;
  TruthError out;
  for (size_t i = 0; i < y.size(); ++i) {
    if (cls[i] < 0 || cls[i] >= qualify::kObjectClassCount) continue;
    const data::PlantedObject o = planted_object(features[i], cls[i]);
    const double truth = target == qualify::kDetectionTarget
                             ? data::planted_detection_probability(d, o)
                             : data::planted_mean_error(d, qualify::kObjectTargets[target], o);
    b += std::pow(y[i] - before_r[i] - truth, 2), a += std::pow(y[i] - after_r[i] - truth, 2), ++out.objects;
  }
  if (out.objects > 0) out.before = std::sqrt(b / out.objects), out.after = std::sqrt(a / out.objects);
  return out;
}

// A spread form's error against the truth: RMS over held-out records of log(predicted / true sigma).
inline TruthError truth_error_spread(const data::PlantedDraw& d, int target, const qualify::obj::AddedSpread& s) {
  double b = 0, a = 0;
  TruthError out;
  for (size_t i = 0; i < s.sd_before.size(); ++i) {
    if (s.held_class[i] < 0 || s.held_class[i] >= qualify::kObjectClassCount) continue;
    const double truth = data::planted_sigma(d, qualify::kObjectTargets[target], planted_object(s.held_features[i], s.held_class[i]));
    if (!(truth > 0) || !(s.sd_before[i] > 0) || !(s.sd_after[i] > 0)) continue;
    b += std::pow(std::log(s.sd_before[i] / truth), 2), a += std::pow(std::log(s.sd_after[i] / truth), 2), ++out.objects;
  }
  if (out.objects > 0) out.before = std::sqrt(b / out.objects), out.after = std::sqrt(a / out.objects);
  return out;
}

// The truth figure (see above) of the term that names the planted effect, from the loop's typed
// result; a draw where nothing names it keeps NaN and is not recalled.
inline void truth_score(const data::PlantedDraw& d, const qualify::obj::ObjectLoopResult& R, DrawScore& s) {
  TruthError t;
  if (d.effect.target == data::kFalsePositivesTarget) {
    if (s.named) t.before = s.before, t.after = s.after;
  } else if (R.spread && names_planted(d.effect, R.candidates[R.spread->candidate])) {
    t = truth_error_spread(d, R.candidates[R.spread->candidate].target, *R.spread);
  } else {
    for (const qualify::obj::AddedBias& a : R.added) {
      const qualify::obj::Candidate& c = R.candidates[a.candidate];
      if (!names_planted(d.effect, c)) continue;
      const qualify::obj::Judged& J = a.judged;
      t = truth_error(d, c.target, J.held_y, J.before_r, J.after_r, J.held_features, J.held_class);
      break;
    }
  }
  s.truth_before = t.before, s.truth_after = t.after, s.truth_objects = t.objects;
  s.truth_recalled = s.named && t.after <= kRecallRatio * t.before;
}

struct DrawResult {
  data::PlantedDraw draw;
  DrawScore score;
  double seconds = 0;      // write + load + loop
  std::string error;       // the loop or the generator threw (the draw counts as missed)
  nlohmann::json added;    // what the loop added
  nlohmann::json top;      // the loop's ranking[0]
  data::PlantedStats ideal;  // what an ideal refit of the planted effect could reach
};

inline nlohmann::json to_json(const data::PlantedDraw& d) {
  nlohmann::json seqs = nlohmann::json::array();
  for (const auto& s : d.sequences) seqs.push_back({{"name", s.name}, {"first_frame", s.first_frame}, {"frames", s.frames}});
  const auto& b = d.base;
  return {{"family", data::to_string(d.effect.family)},
          {"seed", d.seed},
          {"feature", d.effect.feature},
          {"features", d.effect.features},
          {"target", d.effect.target},
          {"params", d.effect.params},
          {"sequences", seqs},
          {"base", {{"sigma_along", b.along}, {"sigma_across", b.across}, {"sigma_length", b.length},
                    {"sigma_width", b.width}, {"sigma_height", b.height}, {"sigma_heading", b.heading},
                    {"detection", b.detection}, {"occlusion_loss", b.occlusion_loss}, {"fp_rate", b.fp_rate}}}};
}

inline nlohmann::json to_json(const DrawResult& r) {
  auto num = [](double v) { return std::isnan(v) ? nlohmann::json(nullptr) : nlohmann::json(v); };
  return {{"truth", to_json(r.draw)},          {"recalled", r.score.recalled},
          {"named", r.score.named},            {"other_add", r.score.other_add},
          {"absorbed", r.score.absorbed},         {"recalled_above_floor", r.score.above_floor},
          {"before", num(r.score.before)},     {"after", num(r.score.after)},
          {"seconds", r.seconds},              {"error", r.error},
          {"added", r.added},                  {"loop_top", r.top},
          {"planted_candidates", r.score.candidates},
          {"recalled_where_planted", r.score.where_recalled},
          {"before_where_planted", num(r.score.where_before)}, {"after_where_planted", num(r.score.where_after)},
          {"objects_where_planted", r.score.where_objects},
          {"recalled_truth", r.score.truth_recalled},
          {"truth_before", num(r.score.truth_before)}, {"truth_after", num(r.score.truth_after)},
          {"truth_objects", r.score.truth_objects},
          {"ideal_before", num(r.ideal.ideal_before)}, {"ideal_after", num(r.ideal.ideal_after)}};
}

// One draw in work/<family>_<seed> (removed afterwards unless keep).
inline DrawResult run_draw(data::PlantedFamily family, const data::PlantedTrackingOptions& o,
                           const std::filesystem::path& work, const qualify::LoopOptions& lo = {}, bool keep = false) {
  DrawResult r;
  const auto t0 = std::chrono::steady_clock::now();
  const std::filesystem::path dir = work / (data::to_string(family) + "_" + std::to_string(o.seed));
  try {
    r.draw = data::plan_planted_tracking(family, o);
    std::filesystem::remove_all(dir);
    r.ideal = data::write_planted_tracking(dir, r.draw);
    // What qualify::loop_objects returns (no plots here), with the typed result kept for scoring.
    const qualify::TrackingData data = qualify::load_tracking(dir, "", "pointrcnn", 2);
    const qualify::obj::ObjectLoopResult R = qualify::obj::run_object_loop(data, lo);
    const nlohmann::json j = qualify::obj::report_json(R);
    r.score = score_draw(r.draw.effect, j);
    score_where_planted(r.draw, R, r.score);
    truth_score(r.draw, R, r.score);
    r.score.above_floor = recalled_above_floor(r.score, r.ideal.ideal_after);
    r.added = nlohmann::json::array();
    for (const AddedEffect& a : loop_added_effects(j))
      r.added.push_back({{"feature", a.feature}, {"target", a.target}, {"kind", a.kind}, {"before", a.before},
                         {"after", a.after}});
    if (j.contains("ranking") && !j["ranking"].empty()) r.top = j["ranking"][0];
  } catch (const std::exception& e) {
    r.error = e.what();
    r.draw.effect.family = family;
  }
  if (!keep) std::filesystem::remove_all(dir);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace lidarsim::bench
