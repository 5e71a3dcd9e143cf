// The object loop's report (object_loop.h): the JSON written from ObjectLoopResult alone, and
// the decisions' names.
#include <cmath>
#include <iterator>

#include "qualify/objects/object_loop.h"

namespace lidarsim::qualify::obj {

namespace {

constexpr const char* kDecisionNames[] = {
    "pending",     "added",          "rejected_by_noise", "rejected_by_distribution", "cannot_decide",
    "used_by_model", "below_threshold", "interval_reaches_zero", "selection_reaches_zero", "line_not_over_table", "bias_added_first", "not_in_manager",
    "top_not_a_term", "one_per_target", "max_effects",     "one_spread_form"};
static_assert(std::size(kDecisionNames) == static_cast<size_t>(DecisionKind::Count));

nlohmann::json number_or_null(double v) { return std::isnan(v) ? nlohmann::json(nullptr) : nlohmann::json(v); }

nlohmann::json ranked(const ObjectLoopResult& R, const std::vector<int>& list) {
  nlohmann::json out = nlohmann::json::array();
  for (int i : list) {
    const Candidate& c = R.candidates[i];
    out.push_back({{"feature", kObjectFeatures[c.feature]}, {"score", c.score},
                   {"target", kObjectTargets[c.target]}, {"kind", to_string(c.kind)}, {"interval95", c.interval},
                   {"selection_lower_bound", number_or_null(c.selection_lower)},
                   {"passes_ranking_tests", passes_ranking(c, R.options.threshold)}});
  }
  return out;
}

// Per feature and target the best score of the bias forms (spread: of the spread forms).
nlohmann::json score_matrix(const ObjectLoopResult& R, bool spread) {
  nlohmann::json m = nlohmann::json::object();
  for (const Candidate& c : R.candidates) {
    if (is_spread(c.kind) != spread) continue;
    const std::string& fn = kObjectFeatures[c.feature];
    const std::string& tn = kObjectTargets[c.target];
    if (!m[fn].contains(tn) || m[fn][tn].get<double>() < c.score) m[fn][tn] = c.score;
  }
  return m;
}

// Every candidate tested, with what became of it and why.
nlohmann::json candidates_json(const ObjectLoopResult& R) {
  nlohmann::json cj = nlohmann::json::array();
  for (size_t i = 0; i < R.candidates.size(); ++i) {
    const Candidate& c = R.candidates[i];
    cj.push_back({{"target", kObjectTargets[c.target]},
                  {"feature", kObjectFeatures[c.feature]},
                  {"kind", to_string(c.kind)},
                  {"form_fold1", c.form},
                  {"effect_size", c.effect_size},
                  {"score", c.score},
                  {"interval95", c.interval},
                  {"significant", c.interval[0] > 0},
                  {"selection_lower_bound", number_or_null(c.selection_lower)},
                  {"selection_family", c.selection_family},
                  {"vs_table_interval95", is_mean_line(c.kind) ? nlohmann::json(c.vs_table) : nlohmann::json(nullptr)},
                  {"error_metric", is_spread(c.kind)              ? "spread error"
                                   : c.target == kDetectionTarget ? "deviance per object"
                                                                  : "RMS residual"},
                  {"error_before", c.error_before},
                  {"error_after", c.error_after},
                  {"held_out_objects", c.n},
                  {"folds", R.fold_schemes[c.fold_set]},
                  {"decision", decision_label(R.decisions[i], c)},
                  {"reason", R.decisions[i].reason}});
  }
  return cj;
}

// The added top bias form as refitted on every sequence.
nlohmann::json bias_effect_json(const ObjectLoopResult& R) {
  const Candidate& top = R.top_candidate();
  const ClassTables& tab = R.top_whole.table;
  nlohmann::json e = {{"feature", kObjectFeatures[top.feature]},
                      {"target", kObjectTargets[top.target]},
                      {"kind", to_string(top.kind) +
                                   (top.kind == Kind::RateGain
                                        ? ": one gain on the detection probability inside a window of the feature "
                                          "with fitted edges (pooled over classes), the range x visibility cells "
                                          "refitted with it by the base model's rule on every sequence"
                                    : top.kind == Kind::MeanRelativeLine
                                        ? ": the object's own size x a per-class line in the feature (pooled for "
                                          "classes with < 200 fit samples), the bias a share of the size (\"bias\" "
                                          "below: the share), refitted jointly with per-class range-bin offsets on "
                                          "every sequence"
                                    : is_window(top.kind)
                                        ? ": one bias inside a window of the feature with fitted edges (pooled over "
                                          "classes), refitted jointly with per-class range-bin offsets on every sequence"
                                        : ": per-class per-bin bias table (pooled for classes with < 200 fit "
                                          "samples), refitted jointly with per-class range-bin offsets on every "
                                          "sequence")},
                      {"pooled", {{"edges", tab.pooled.edges}, {"bias", tab.pooled.value}}}};
  for (int c = 0; c < kObjectClassCount; ++c)
    if (tab.own[c]) e[kObjectClasses[c]] = {{"edges", tab.per_class[c].edges}, {"bias", tab.per_class[c].value}};
  if (R.top_whole.relative >= 0) e["relative_to"] = kObjectFeatures[R.top_whole.relative];
  if (R.top_whole.has_gain())  // rate_gain: the cells are refitted with it, the gain multiplies them
    e["pooled"]["gain"] = R.top_whole.gain.pooled.value, e["pooled"]["edges"] = R.top_whole.gain.pooled.edges;
  if (R.options.shrink_terms != TermShrink::Off) {  // per bin: the share of the fitted (deviation) kept
    e["pooled"]["shrink_factor"] = R.top_whole.factor.pooled.value;
    for (int c = 0; c < kObjectClassCount; ++c)
      if (tab.own[c]) e[kObjectClasses[c]]["shrink_factor"] = R.top_whole.factor.per_class[c].value;
  }
  return e;
}

// The added spread form: its fields replace the single-effect fields of the bias form.
void spread_fields(const ObjectLoopResult& R, nlohmann::json& j) {
  const AddedSpread& s = *R.spread;
  const Candidate& sp = R.candidates[s.candidate];
  const std::string sf = kObjectFeatures[sp.feature], stn = kObjectTargets[sp.target];
  j["metric"] = "held-out spread error of " + stn + ": in 10 equal-count bins of " + sf +
                ", log(measured sd / model sd), RMS over bins; both folds";
  j["before"] = sp.error_before;
  j["after"] = sp.error_after;
  j["error_metric"] = "spread error";
  j["error_before"] = sp.error_before;
  j["error_after"] = sp.error_after;
  j["before_simulated"] = number_or_null(s.before_simulated);
  j["after_simulated"] = number_or_null(s.after_simulated);
  j["added_effect"] = sf;
  j["added_kind"] = to_string(sp.kind);
  j["model_term"] = sf;
  j["model_term_on"] = "errors." + stn + ".scale";
  j.erase("model_term_absent_because");
  j["effect"] = {{"feature", sf},
                 {"target", stn},
                 {"kind", to_string(sp.kind) + ": the error's sigma x scale per bin, pooled over classes, fitted on "
                                               "every sequence"},
                 {"edges", s.whole.scale.edges},
                 {"scale", s.whole.scale.value}};
}

// Per class: re-simulated held-out histogram intersection before / after and whether it kept the term.
nlohmann::json distribution_entry(const Judged& J) {
  nlohmann::json d = nlohmann::json::object();
  for (int c = 0; c < kObjectClassCount; ++c)
    if (J.dist_before[c] >= 0 || J.dist_after[c] >= 0)
      d[kObjectClasses[c]] = {{"before", J.dist_before[c]},
                              {"after", J.dist_after[c]},
                              {"rms_before", J.class_rms[c].first},
                              {"rms_after", J.class_rms[c].second},
                              {"kept", J.classes[c]}};
  return d;
}

// Each fold's shrink factors per bin (pooled, then the classes with their own table); null when not shrunk.
nlohmann::json shrink_entry(const ObjectLoopResult& R, const Judged& J) {
  if (R.options.shrink_terms == TermShrink::Off) return nlohmann::json(nullptr);
  nlohmann::json out = nlohmann::json::array();
  for (const Refit& r : J.refs) {
    nlohmann::json f = {{"pooled", {{"factor", r.factor.pooled.value}, {"se", r.se.pooled.value}}}};
    for (int c = 0; c < kObjectClassCount; ++c)
      if (r.factor.own[c])
        f[kObjectClasses[c]] = {{"factor", r.factor.per_class[c].value}, {"se", r.se.per_class[c].value}};
    out.push_back(f);
  }
  return out;
}

// Every bias form added (the top one first), each with its own before -> after; the simulated
// "after" is with the model that carries all of them.
nlohmann::json added_effects_json(const ObjectLoopResult& R) {
  nlohmann::json aj = nlohmann::json::array();
  for (const AddedBias& a : R.added) {
    const Candidate& c = R.candidates[a.candidate];
    const Judged& J = a.judged;
    aj.push_back({{"feature", kObjectFeatures[c.feature]},
                  {"shrink_per_fold", shrink_entry(R, J)},
                  {"target", kObjectTargets[c.target]},
                  {"kind", to_string(c.kind)},
                  {"score", c.score},
                  {"model_term_on",
                   c.target == kDetectionTarget ? "detection_probability" : "errors." + kObjectTargets[c.target]},
                  {"before", rms(J.before_r)},
                  {"after", rms(J.after_r)},
                  {"before_simulated", number_or_null(a.before_simulated)},
                  {"after_simulated", number_or_null(a.after_simulated)},
                  {"change_interval95", J.change},
                  {"held_out_tracks", J.tracks},
                  {"held_out_tracks_better", J.tracks_better},
                  {"distribution", distribution_entry(J)},
                  // false: the histogram half is reported only (the term explains most of the spread)
                  {"distribution_decides", J.distribution_decides}});
  }
  return aj;
}

// The top one's fold set: per fold its sequences and the held-out error before / after.
nlohmann::json folds_json(const ObjectLoopResult& R) {
  nlohmann::json fj = nlohmann::json::array();
  const Judged& J = R.top_judged;
  for (int k = 0; k < 2; ++k) {
    fj.push_back({{"fit_sequences", R.fit_names[k]},
                  {"held_out_sequences", R.held_names[k]},
                  {"before", J.fold_rms[k].first},
                  {"after", R.top_added() ? J.fold_rms[k].second : J.fold_rms[k].first}});
    if (R.spread) fj[k]["before"] = R.spread->fold[k].first, fj[k]["after"] = R.spread->fold[k].second;
  }
  return fj;
}

// The top bias form: what it was judged on, and whether it was added or why not.
void top_fields(const ObjectLoopResult& R, nlohmann::json& j) {
  const Candidate& top = R.top_candidate();
  const Judged& J = R.top_judged;
  const std::string& fn = kObjectFeatures[top.feature];
  const std::string& tn = kObjectTargets[top.target];
  const bool add = J.add, det = top.target == kDetectionTarget;
  j["metric"] = "held-out RMS residual of " + tn +
                (det ? " (detected 0/1 minus the model's detection probability)"
                     : " (measured error minus the model's conditional mean error)") +
                ", both folds of the cross-fit";
  j["before"] = rms(J.before_r);
  j["after"] = rms(J.after_r);
  // The same RMS with what the KPI manager uses (base model / refitted model).
  j["before_simulated"] = number_or_null(R.top_before_simulated);
  j["after_simulated"] = number_or_null(R.top_after_simulated);
  j["model_term"] = R.term() ? nlohmann::json(fn) : nlohmann::json(nullptr);
  if (R.term()) j["model_term_on"] = det ? "detection_probability" : "errors." + tn;
  if (!R.term()) j["model_term_absent_because"] = R.not_a_term;
  j["added_effect"] = add ? nlohmann::json(fn) : nlohmann::json(nullptr);
  if (J.candidate) {
    j["change_interval95"] = J.change;  // of the winsorised RMS
    j["held_out_tracks"] = J.tracks;
    j["held_out_tracks_better"] = J.tracks_better;
  }
  if (J.candidate && !add)
    j["rejected_effect"] = {{"feature", fn},
                            {"target", tn},
                            {"held_out_after", J.candidate_after},
                            {"change_interval95", J.change},
                            {"why", J.distribution_rejected
                                        ? "the re-simulated held-out distribution of the KPI got worse for every class"
                                    : top.undecided.empty()
                                        ? "the refit did not lower the held-out RMS beyond the track-to-track noise"
                                        : "the data cannot decide: " + top.undecided}};
  j["error_metric"] = det ? "deviance per object" : "RMS residual";
  j["error_before"] = top.error_before;
  j["error_after"] = add ? top.error_after : top.error_before;
  j["added_kind"] = add ? nlohmann::json(to_string(top.kind)) : nlohmann::json(nullptr);
  if (add) j["effect"] = bias_effect_json(R);
  j["held_out_samples"] = J.before_r.size();
}

}  // namespace

std::string to_string(DecisionKind k) { return kDecisionNames[static_cast<int>(k)]; }

std::string decision_label(const Decision& d, const Candidate& c) {
  const std::string& fn = kObjectFeatures[c.feature];
  switch (d.kind) {
    case DecisionKind::Added: return "added";
    case DecisionKind::RejectedByNoise: return "rejected: the refit did not beat the track-to-track noise";
    case DecisionKind::RejectedByDistribution:
      return "rejected: the re-simulated held-out distribution of the KPI got worse for every class";
    case DecisionKind::CannotDecide: return "the data cannot decide: " + c.undecided;
    case DecisionKind::UsedByModel:
      return "not ranked: the base KPI model already conditions " + kObjectTargets[c.target] + " on " + fn +
             " in this form";
    case DecisionKind::BelowThreshold: return "ruled out: held-out score below the threshold";
    case DecisionKind::IntervalReachesZero: return "ruled out: interval reaches 0";
    case DecisionKind::SelectionReachesZero:
      return "ruled out: its bound over the " + std::to_string(c.selection_family) +
             " candidates picked from reaches 0 (a chance best)";
    case DecisionKind::LineNotOverTable: return "ruled out: the line does not beat the table on the same held-out tracks";
    case DecisionKind::BiasAddedFirst: return "not tried: a bias form was added first";
    case DecisionKind::NotInManager:
      return "not added: the KPI manager cannot compute \"" + fn + "\" from a truth object, so " +
             (is_spread(c.kind) ? "a spread form on it cannot become a model term"
                                : "it is added only as the top effect (without a model term)");
    case DecisionKind::TopNotATerm: return "not tried: further bias forms are tried only once the top one is a model term";
    case DecisionKind::OnePerTarget: return "not added: at most one bias form per target is added per run, the best first";
    case DecisionKind::MaxEffects: return "not tried: the most bias forms per run (--max-effects) were added already";
    case DecisionKind::OneSpreadForm: return "not tried: only the best spread form is tried per run";
    case DecisionKind::Pending:
    case DecisionKind::Count: break;
  }
  return "undecided";  // a step left it Pending: a defect of the loop, visible in the report
}

nlohmann::json report_json(const ObjectLoopResult& R) {
  const LoopOptions& o = R.options;
  nlohmann::json j;
  j["domain"] = "objects";
  top_fields(R, j);
  if (!o.out_model.empty()) j["out_model"] = o.out_model.string();
  j["ranking"] = ranked(R, R.ranking);
  j["used_by_model"] = ranked(R, R.used);
  j["spread_ranking"] = ranked(R, R.spread_ranking);
  j["threshold"] = o.threshold;
  j["distribution_seeds"] = o.distribution_seeds;  // of the per-class distribution check
  j["score_definition"] =
      "every feature x target x form is a candidate (kinds: mean_table, mean_window, mean_line on an error, and on a size error "
      "mean_relative_line (the object's own length, width or height x a line in the feature: a share of its size); "
      "rate_table, rate_window, rate_gain on detection; spread_table, spread_window, spread_growth (range only: sigma x (range / its range "
      "bin's mean)^k), spread_line (sigma x (1 + b x) on x clamped to its 1-99 % range, with a level per class x range bin "
      "refitted with it) on an error's sigma). Each is fitted on a fold's fit "
      "sequences and scored on its held-out ones, pooled over the two-fold cross-fit (fit on the even-indexed "
      "sequences, judge the odd-indexed ones, and the other way round): mean forms by the held-out R^2 of the "
      "winsorised residual (measured - base model) against the fit split's mean; rate forms by the deviance R^2 "
      "1 - D_after / D_before (Bernoulli deviance with the model's detection probability); spread forms by "
      "1 - exp(-(G_before - G_after) / n) with G the Gaussian deviance around the fit split's per-class range-bin "
      "mean and sd. Tables: 10 equal-count bins on the fit split, shrunk by n/(n+5), per class where >= 200 "
      "samples; windows: the best contiguous run of 40 equal-count bins (a step when it touches an end); lines: a "
      "least-squares line per class (per class where >= 200 samples) on the feature clamped to its 1-99 % range, "
      "carried as 64 equal-width bins over that range widened by its span on each side, a line (absolute or relative) is ranked only where it beats "
      "the table (vs_table_interval95: block-bootstrap 95 % interval of its score minus the mean_table's on the "
      "same held-out tracks, above 0). Bias forms "
      "are refitted with per-class range-bin (detection: range x visibility) offsets, 4 backfitting passes. "
      "interval95 = basic block bootstrap over held-out tracks (a track and its sequence are never on both sides). "
      "selection_lower_bound = the score's lower bound simultaneous over its family (every bias form the base model "
      "does not hold, or every such spread form), single-step max-T block bootstrap at 97.5 %: it holds whichever "
      "candidate the scores pick, and a candidate is ranked for adding only when it lies above 0. "
      "ranking: per feature its best form; those that pass the ranking's tests (passes_ranking_tests: score at "
      "least the threshold, interval95 and selection_lower_bound above 0, a line over its table) first, each "
      "group by score. "
      "The top bias form is added when its score is at least the threshold and the refit lowers the held-out loss "
      "(winsorised RMS; detection: deviance) with a block-bootstrap 95% interval of the change below 0; each "
      "further bias form (the best of every other target) passes the same test; on an error, each (top or "
      "further) is kept only for the classes whose own held-out residual falls and whose re-simulated held-out "
      "distribution (histogram intersection of the KPI manager's errors, distribution_seeds seeds, against the "
      "measured held-out errors, both folds pooled) does not get worse (rejected when no class keeps it); the "
      "histogram is reported only (distribution_decides false) for a term scoring >= 0.5, which explains most of "
      "its error's spread; if no bias form is added, "
      "the top spread form is added when its score is at least the threshold and its interval lies above 0. "
      "With at most 3 sequences the features fixed to the sensor (azimuth) are judged on folds of time blocks "
      "instead: each sequence cut into 4 blocks of its tracks by middle frame, fit on the even blocks and judge the "
      "odd ones, and the other way round. A candidate judged on one sequence per fold (a feature that can depend "
      "on the place) or on fewer than 10 held-out tracks in a fold is reported as \"the data cannot decide\" "
      "rather than ruled out or rejected";
  j["scores"] = score_matrix(R, false);
  j["spread_scores"] = score_matrix(R, true);
  j["candidates"] = candidates_json(R);
  j["false_positives"] = fp_json(R.false_positives, o.threshold);
  if (R.spread) spread_fields(R, j);
  j["added_effects"] = added_effects_json(R);
  j["folds"] = folds_json(R);
  j["fold_scheme"] = R.top_scheme;
  if (R.fold_schemes.size() > 1)
    j["time_folds"] = {{"features", kSensorFixedFeatures},
                       {"blocks_per_sequence", kTimeBlocks},
                       {"why", std::to_string(R.sequences) +
                                   " sequences: the features fixed to the sensor are judged on blocks of time within "
                                   "each sequence (tracks kept whole), the others on whole sequences"}};
  if (o.pool_track_spread) {
    nlohmann::json tj = nlohmann::json::object();  // track_std after / before, per class: length, width, height
    for (int c = 0; c < kObjectClassCount; ++c)
      if (c < static_cast<int>(R.track_spread_factor.size())) tj[kObjectClasses[c]] = R.track_spread_factor[c];
    j["track_spread_pooling"] = tj;
  }
  if (!R.plot.empty()) j["plot"] = R.plot;
  return j;
}

}  // namespace lidarsim::qualify::obj
