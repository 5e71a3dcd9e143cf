#pragma once
// The object loop's steps and its typed result (internal to qualify/). loop_objects (objects.h)
// is report_json(run_object_loop(...)), and run_object_loop is six named steps:
//   make_fold_sets  the cross-fit's folds: whole sequences; with few sequences also time blocks
//   rank            every candidate (feature x target x form) judged on the held-out folds, with a
//                   bound that holds whichever candidate the scores pick (object_selection.h)
//   judge           one bias form refitted per fold: the held-out change beyond the track-to-track
//                   noise and, for an error term, the re-simulated distribution per class
//   add             the top bias form, then the best bias form of each other target, else a spread form
//   resimulate      what the KPI manager makes of the added terms on the held-out truth objects
//   refit           the terms on every sequence, the false positives, the model written
// Each candidate's Decision is recorded by the step that makes it (rank: ruled out, used by the
// model, the data cannot decide; judge / add: added, rejected, not tried and why), and the JSON is
// written from the result alone.
#include <array>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_false_positives.h"
#include "qualify/objects/object_folds.h"
#include "qualify/objects/objects.h"

namespace lidarsim::qualify::obj {

// What became of a candidate. The JSON's "decision" is a fixed sentence per kind
// (decision_label); Decision::reason says why in this run's numbers, in words a user acts on.
enum class DecisionKind {
  Pending,                 // not decided yet (never in a finished result)
  Added,                   // judged and added (as a model term where the KPI manager computes it)
  RejectedByNoise,         // judged: the refit did not lower the held-out loss beyond the track-to-track noise
  RejectedByDistribution,  // judged: the re-simulated held-out distribution got worse for every class
  CannotDecide,            // the held-out data cannot judge it (Candidate::undecided)
  UsedByModel,             // the base KPI model holds this form already: never ranked
  BelowThreshold,          // held-out score below the threshold
  IntervalReachesZero,     // the score's 95 % interval reaches 0
  SelectionReachesZero,    // its bound simultaneous over the candidates picked from reaches 0 (object_selection.h)
  LineNotOverTable,        // a mean_line that does not beat the mean_table on the same held-out tracks
  BiasAddedFirst,          // a spread form: a bias form was added in this run
  NotInManager,            // the KPI manager cannot compute the feature, so it cannot become a term
  TopNotATerm,             // a further bias form: tried only once the top one is a model term
  OnePerTarget,            // a better bias form on the same target was added or tried first
  MaxEffects,              // a further bias form: LoopOptions::max_effects reached
  OneSpreadForm,           // a spread form: only the best spread form is tried per run
  Count
};
std::string to_string(DecisionKind k);  // "added", "rejected_by_noise", ...

struct Decision {
  DecisionKind kind = DecisionKind::Pending;
  std::string reason;  // in words a user acts on, with this run's numbers
};
// The JSON's "decision" for candidate c: one sentence per kind, naming c where the kind needs it.
std::string decision_label(const Decision& d, const Candidate& c);

// One way of cutting the data into the cross-fit's two folds, with what is judged on it: the
// held-out tracks as bootstrap blocks, the truth motion the KPI manager re-simulates, and each
// fold's model with the terms added so far. Built in place (the folds' Splits point into them).
struct FoldSet {
  std::string scheme;                  // "sequences" or "time blocks"
  TimeBlocks time;                     // the time blocks, when the folds are made of them
  const TrackingData* data = nullptr;  // what the folds' indices refer to: the loop's data or time.data
  std::array<Fold, 2> folds;
  std::array<std::vector<std::vector<int>>, 2> block;  // [fold][target][held record]: its track's block
  size_t nblocks = 0;
  std::vector<sensor::CalibrationSequence> motion;
  std::array<sensor::KpiModel, 2> current;
};

// A bias candidate judged for adding: its refit per fold, the held-out residuals before and
// after, and the block-bootstrap interval of the change.
struct Judged {
  std::array<Refit, 2> refs;
  // after_r = before_r when not added, and for the records of classes the term is not kept for
  std::vector<double> before_r, after_r;
  // Per held-out record (the order of before_r): its features (kObjectFeatures), so the error can
  // be read on any group of objects (bench/campaign_objects.h: where a planted effect acts).
  std::vector<std::vector<double>> held_features;
  std::vector<int> held_class;  // per held-out record: its class (kObjectClasses; -1 other)
  // Per held-out record: its outcome (the error, or detected 0/1), so the model's prediction before
  // (held_y - before_r) and after (held_y - after_r) can be scored against a known truth.
  std::vector<double> held_y;
  std::array<std::pair<double, double>, 2> fold_rms{};  // per fold: RMS before, after
  std::array<double, 2> change{0, 0};  // of the winsorised RMS (detection: deviance per object)
  int tracks = 0, tracks_better = 0;
  bool candidate = false, add = false;  // candidate: its score clears the threshold
  double candidate_after = kNaN;        // the held-out RMS with it, also when not added
  // Error targets: the re-simulated held-out distribution per class before / after the term
  // (-1: too few samples) and the classes that keep it.
  PerClass<double> dist_before{-1, -1, -1}, dist_after{-1, -1, -1};
  PerClass<bool> classes{true, true, true};
  PerClass<std::pair<double, double>> class_rms{};  // winsorised held-out RMS before, after
  bool distribution_decides = true;  // the histogram half of the check decides (score < kDistributionExemptScore)
  bool distribution_rejected = false;
};

// A term whose held-out score (R^2) is at least this explains most of its error's spread: the
// distribution check's histogram half is reported for it, not deciding (judge), whatever its rank.
inline constexpr double kDistributionExemptScore = 0.5;

// A bias form added (the top one first), with the held-out RMS of its target re-simulated by the
// KPI manager with each fold's base and with the model carrying every added term.
struct AddedBias {
  int candidate = 0;  // index into ObjectLoopResult::candidates
  Judged judged;
  double before_simulated = kNaN, after_simulated = kNaN;
};

// The spread form added when no bias form is.
struct AddedSpread {
  int candidate = 0;
  // Per held-out record of both folds: its features, class, and the sigma predicted before (the
  // fold's base) and after (with the spread form), so the form can be scored against a known truth.
  std::vector<std::vector<double>> held_features;
  std::vector<int> held_class;
  std::vector<double> sd_before, sd_after;
  std::array<std::pair<double, double>, 2> fold{};  // held-out spread error per fold: before, after
  double before_simulated = kNaN, after_simulated = kNaN;
  Effect whole;  // refitted on every sequence
};

struct ObjectLoopResult {
  LoopOptions options;
  int sequences = 0;
  std::vector<std::string> fold_schemes;  // per fold set: "sequences", then "time blocks" if used
  std::vector<Candidate> candidates;      // every feature x target x form judged
  std::vector<Decision> decisions;        // per candidate
  // Indices into candidates: the best bias form per feature of those the base model does not
  // hold (ranking) and of those it does (used), the best spread form per feature; those that pass
  // the ranking's tests first, then by score (best_per_feature).
  std::vector<int> ranking, used, spread_ranking;
  int top = 0;  // ranking.front()
  Judged top_judged;
  // The top one's held-out RMS re-simulated with each fold's base and with the model carrying every
  // added term (the base again when nothing is added).
  double top_before_simulated = kNaN, top_after_simulated = kNaN;
  std::string not_a_term;  // why the top one is not a model term ("" when it is)
  std::vector<AddedBias> added;  // the top one first when added, then the further bias forms
  std::optional<AddedSpread> spread;
  Refit top_whole;  // the top bias form refitted on every sequence (reported when added)
  std::array<std::vector<std::string>, 2> fit_names, held_names;  // the top one's fold set, per fold
  std::string top_scheme;
  FpAnalysis false_positives;
  // Per class: length, width, height; of the model fitted on every sequence.
  std::vector<std::array<double, 3>> track_spread_factor;
  std::string plot;  // the residual PNG's file name in options.plots_dir ("" when none)

  const Candidate& top_candidate() const { return candidates[top]; }
  bool top_added() const { return top_judged.add; }
  bool term() const { return not_a_term.empty(); }
};

// The loop's working state: the data, its options and its fold sets.
struct LoopContext {
  const TrackingData& data;
  const LoopOptions& options;
  sensor::FitOptions fit;
  std::vector<std::unique_ptr<FoldSet>> sets;
  int nvis = 0;
  FoldSet& set_of(const Candidate& c) const { return *sets[c.fold_set]; }
};

// The steps, in order (object_loop*.cpp).
void make_fold_sets(LoopContext& L);
void rank(LoopContext& L, ObjectLoopResult& R);
Judged judge(LoopContext& L, const Candidate& c);
void add(LoopContext& L, ObjectLoopResult& R);
void resimulate(LoopContext& L, ObjectLoopResult& R);
void refit(LoopContext& L, ObjectLoopResult& R);

ObjectLoopResult run_object_loop(const TrackingData& data, const LoopOptions& options = {});
nlohmann::json report_json(const ObjectLoopResult& R);

// Whether a candidate passes the tests the ranking alone applies: its score clears the threshold,
// its 95 % interval lies above 0 and its selection-aware bound too (when computed), and a line
// beats the table (line_over_table).
bool passes_ranking(const Candidate& c, double threshold);
// The rankings' order: candidates that pass first, then by score.
bool ranks_before(const Candidate& a, const Candidate& b, double threshold);
// A ranking (ObjectLoopResult::ranking, used, spread_ranking): per feature its first candidate of
// the forms asked for (spread or bias) among those the base model holds (used) or the others, in
// the order of ranks_before, so a form ruled out by its own interval never hides one that passes.
std::vector<int> best_per_feature(const std::vector<Candidate>& cands, bool spread, bool used, double threshold);

// Whether the KPI manager computes the feature from a truth object (sensor::kConditionalFeatures).
bool in_manager(const std::string& feature);

}  // namespace lidarsim::qualify::obj
