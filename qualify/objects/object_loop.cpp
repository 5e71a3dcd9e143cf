// `lidar-qualify loop objects`: the two-fold cross-fit loop (see objects.h), as the steps of
// object_loop.h. Here: the loop in order, its fold sets, and the ranking.
#include <algorithm>
#include <map>
#include <set>

#include "common/error.h"
#include "qualify/objects/object_loop.h"
#include "qualify/objects/object_selection.h"
#include "qualify/objects/objects.h"
#include "qualify/report.h"
#include "sensor/kpi_manager.h"

namespace fs = std::filesystem;

namespace lidarsim::qualify {

namespace obj {

namespace {

// Below this many held-out tracks in a fold the block bootstrap has too few blocks to judge.
constexpr int kMinHeldOutTracks = 10;

void build_fold_set(FoldSet& S, const std::array<std::vector<int>, 2>& sides, const LoopOptions& options,
                    const sensor::FitOptions& opt) {
  for (Fold& k : S.folds) k.pool_track_spread = options.pool_track_spread;
  make_fold(S.folds[0], *S.data, sides[0], sides[1], opt);
  make_fold(S.folds[1], *S.data, sides[1], sides[0], opt);
  for (Fold& k : S.folds) k.shrink_terms = options.shrink_terms;
  // Held-out tracks are the bootstrap blocks: a track's errors are correlated frame to frame.
  std::map<std::pair<int, int>, int> block_id;
  for (int k = 0; k < 2; ++k)
    for (int t = 0; t < kObjectTargetCount; ++t) {
      S.block[k].emplace_back();
      for (const ObjectRecord* r : S.folds[k].held_r[t].rec)
        S.block[k][t].push_back(
            block_id.try_emplace({r->seq, r->track}, static_cast<int>(block_id.size())).first->second);
    }
  S.nblocks = block_id.size();
  S.motion = sensor::with_truth_motion(S.data->calib);
  S.current = {S.folds[0].base, S.folds[1].base};
}

// Why the held-out data of S cannot decide on candidate c ("" when it can): a feature that can
// depend on the place judged on single sequences cannot tell the feature from the place; any
// candidate judged on few held-out tracks cannot tell an effect from the track-to-track spread.
std::string cannot_decide(const FoldSet& S, const Candidate& c) {
  if (S.scheme == "sequences" && !fixed_to_sensor(kObjectFeatures[c.feature])) {
    size_t fewest = S.folds[0].fit_idx.size();
    for (const Fold& k : S.folds) fewest = std::min({fewest, k.fit_idx.size(), k.held_idx.size()});
    if (fewest < 2)
      return std::to_string(fewest) + " sequence per fold; \"" + kObjectFeatures[c.feature] +
             "\" can depend on the place, so it needs at least 2 sequences on each side (4 in all)";
  }
  for (int k = 0; k < 2; ++k) {
    const auto& b = S.block[k][c.target];
    const int tracks = static_cast<int>(std::set<int>(b.begin(), b.end()).size());
    if (tracks < kMinHeldOutTracks)
      return std::to_string(tracks) + " held-out tracks in fold " + std::to_string(k + 1) + " for " +
             kObjectTargets[c.target] + "; at least " + std::to_string(kMinHeldOutTracks) + " are needed";
  }
  return "";
}

// What the base model conditions the candidate's target on, in words (for UsedByModel).
std::string how_the_model_uses(const Candidate& c) {
  const std::string& f = kObjectFeatures[c.feature];
  if (f == "class") return "it holds one model per class";
  return c.target == kDetectionTarget ? "its detection probability is per range x visibility (occlusion) bin"
                                      : "its sigma is scaled per visibility (occlusion) bin";
}

// The decision the ranking alone makes (Pending: left to the steps that judge and add).
Decision ranked_decision(const Candidate& c, double threshold) {
  const std::string& fn = kObjectFeatures[c.feature];
  const std::string& tn = kObjectTargets[c.target];
  const std::string score = fmt(c.score, 3), interval = "[" + fmt(c.interval[0], 3) + ", " + fmt(c.interval[1], 3) + "]";
  if (used_by_model(c))
    return {DecisionKind::UsedByModel, "not ranked: the base KPI model already conditions " + tn + " on " + fn +
                                           " in this form (" + how_the_model_uses(c) + "); nothing to add"};
  if (!c.undecided.empty() &&
      (c.score < threshold || c.interval[0] <= 0 || !clears_selection(c) || !line_over_table(c)))
    return {DecisionKind::CannotDecide, "the data cannot decide: " + c.undecided};
  if (c.score < threshold)
    return {DecisionKind::BelowThreshold, "ruled out: held-out score " + score + " is below the threshold " +
                                              fmt(threshold, 3) + ": " + fn + " explains too little of " + tn +
                                              " in this form"};
  if (c.interval[0] <= 0)
    return {DecisionKind::IntervalReachesZero, "ruled out: held-out score " + score + ", but its 95 % interval " +
                                                   interval + " reaches 0: no more than the track-to-track spread"};
  if (!clears_selection(c))
    return {DecisionKind::SelectionReachesZero,
            "ruled out: held-out score " + score + " with 95 % interval " + interval + ", but the best of the " +
                std::to_string(c.selection_family) + " candidates scored on the same held-out tracks scores this " +
                "high by chance: its bound simultaneous over them (score - " + fmt(c.selection_critical, 3) +
                " x its bootstrap standard error) is " + fmt(c.selection_lower, 3) +
                ", not above 0; more held-out tracks would tell"};
  if (!line_over_table(c))
    return {DecisionKind::LineNotOverTable,
            "ruled out: held-out score " + score + ", but the line does not beat the table of the same feature on "
                "the same held-out tracks (95 % interval of its score minus the table's [" + fmt(c.vs_table[0], 3) +
                ", " + fmt(c.vs_table[1], 3) + "] reaches 0), so the table is the form kept"};
  return {};
}

}  // namespace

bool passes_ranking(const Candidate& c, double threshold) {
  return c.score >= threshold && c.interval[0] > 0 && clears_selection(c) && line_over_table(c);
}

bool ranks_before(const Candidate& a, const Candidate& b, double threshold) {
  const bool pa = passes_ranking(a, threshold), pb = passes_ranking(b, threshold);
  return pa != pb ? pa : a.score > b.score;
}

// A candidate whose own interval or selection bound reaches 0 is ruled out whatever its score, so
// it must not stand in the way of one that passes: the top form decides what is judged and
// added, and a ruled-out top blocked every other form (a dropout's rate table scoring 0.137
// [0.10, 0.18] was never tried behind its window scoring 0.146 [-0.03, 0.35]).
std::vector<int> best_per_feature(const std::vector<Candidate>& cands, bool spread, bool used, double threshold) {
  std::vector<int> out;
  for (size_t f = 0; f < kObjectFeatures.size(); ++f) {
    int best = -1;
    for (size_t i = 0; i < cands.size(); ++i) {
      const Candidate& c = cands[i];
      if (c.feature == static_cast<int>(f) && is_spread(c.kind) == spread && used_by_model(c) == used &&
          (best < 0 || ranks_before(c, cands[best], threshold)))
        best = static_cast<int>(i);
    }
    if (best >= 0) out.push_back(best);
  }
  std::stable_sort(out.begin(), out.end(),
                   [&](int a, int b) { return ranks_before(cands[a], cands[b], threshold); });
  return out;
}

bool in_manager(const std::string& feature) {
  return std::find(sensor::kConditionalFeatures.begin(), sensor::kConditionalFeatures.end(), feature) !=
         sensor::kConditionalFeatures.end();
}

// Two-fold cross-fit: fold 1 fits on the even-indexed sequences and judges the odd-indexed ones,
// fold 2 the other way round, so every sequence is held out once and judged by a model that
// never saw it. With few sequences one split judges on too few tracks to tell an effect from
// the track-to-track spread (on KITTI: 107 tracks, 3 of which hold a third of the error).
// With at most kTimeFoldsMaxSequences sequences, the features fixed to the sensor are judged on
// a second cross-fit whose folds are blocks of time within each sequence (tracks kept whole):
// fold 1 fits the even blocks of every sequence and judges the odd ones, fold 2 the other way
// round. Every other feature, and the false positives, keep the folds of whole sequences.
void make_fold_sets(LoopContext& L) {
  const int nseq = static_cast<int>(L.data.calib.size());
  std::vector<int> even, odd;
  for (int s = 0; s < nseq; ++s) (s % 2 == 0 ? even : odd).push_back(s);
  L.sets.push_back(std::make_unique<FoldSet>());
  L.sets[0]->scheme = "sequences";
  L.sets[0]->data = &L.data;
  build_fold_set(*L.sets[0], {even, odd}, L.options, L.fit);
  if (nseq <= kTimeFoldsMaxSequences) {
    L.sets.push_back(std::make_unique<FoldSet>());
    FoldSet& T = *L.sets[1];
    T.scheme = "time blocks";
    T.time = split_into_time_blocks(L.data, kTimeBlocks, L.fit);
    T.data = &T.time.data;
    build_fold_set(T, time_block_sides(T.time), L.options, L.fit);
  }
  L.nvis = L.sets[0]->folds[0].base.visibility_bins();
}

// Every candidate effect: each feature x target x form (object_candidates.h), judged on the
// held-out folds of its fold set. Bias forms (mean and rate) are ranked first; a spread form is
// added only when no bias form is (add): an unmodelled bias makes the spread around the model's
// mean look feature-dependent, so the spread is tested again on the next run with the bias in
// the model.
void rank(LoopContext& L, ObjectLoopResult& R) {
  auto set_of = [&](size_t f) { return L.sets.size() > 1 && fixed_to_sensor(kObjectFeatures[f]) ? 1 : 0; };
  for (size_t f = 0; f < kObjectFeatures.size(); ++f)
    for (int t = 0; t < kObjectTargetCount; ++t) {
      const FoldSet& S = *L.sets[set_of(f)];
      bool enough = true;
      for (const Fold& k : S.folds) enough &= k.fit_r[t].r.size() >= 20 && k.held_r[t].r.size() >= 20;
      if (!enough) continue;
      const std::array<std::vector<int>, 2> blocks_t = {S.block[0][t], S.block[1][t]};
      for (Kind kind : kinds_for(t)) {
        if (!kind_applies(kind, kObjectFeatures[f])) continue;
        Candidate c = judge_candidate(S.folds, t, static_cast<int>(f), kind, L.nvis, L.options.bins, blocks_t,
                                      S.nblocks);
        c.fold_set = set_of(f);
        c.undecided = cannot_decide(S, c);
        R.candidates.push_back(std::move(c));
      }
    }
  compare_lines_with_tables(R.candidates);
  // The bias forms and the spread forms are each a family the loop picks from by score (rank,
  // add): each gets a bound that holds whichever of its members the scores pick.
  std::vector<int> bias, spread;
  for (size_t i = 0; i < R.candidates.size(); ++i)
    if (!used_by_model(R.candidates[i])) (is_spread(R.candidates[i].kind) ? spread : bias).push_back(static_cast<int>(i));
  if (L.options.selection_bound) {
    selection_aware_bounds(R.candidates, bias);
    selection_aware_bounds(R.candidates, spread);
  }
  for (const Candidate& c : R.candidates) R.decisions.push_back(ranked_decision(c, L.options.threshold));
  const double thr = L.options.threshold;
  R.ranking = best_per_feature(R.candidates, false, false, thr);
  R.used = best_per_feature(R.candidates, false, true, thr);
  R.spread_ranking = best_per_feature(R.candidates, true, false, thr);
  if (R.ranking.empty()) throw Error("loop objects: too few matched objects to score any feature");
  R.top = R.ranking.front();
}

ObjectLoopResult run_object_loop(const TrackingData& data, const LoopOptions& options) {
  const int nseq = static_cast<int>(data.calib.size());
  if (nseq < 2) throw Error("loop objects: need at least two sequences (one to fit, one held out), got " +
                            std::to_string(nseq));
  LoopContext L{data, options, {}, {}, 0};
  ObjectLoopResult R;
  R.options = options;
  R.sequences = nseq;
  make_fold_sets(L);
  for (const auto& S : L.sets) R.fold_schemes.push_back(S->scheme);
  rank(L, R);
  add(L, R);
  resimulate(L, R);
  refit(L, R);
  return R;
}

}  // namespace obj

nlohmann::json loop_objects(const TrackingData& data, const LoopOptions& options) {
  nlohmann::json j = obj::report_json(obj::run_object_loop(data, options));
  if (!options.plots_dir.empty() && j["false_positives"].contains("persistence")) {
    auto& p = j["false_positives"]["persistence"];
    fs::create_directories(options.plots_dir);
    p["plot_caption"] = obj::write_fp_tracks_png(options.plots_dir / "fp_track_lengths.png", p);
    p["plot"] = "fp_track_lengths.png";
  }
  return j;
}

}  // namespace lidarsim::qualify
