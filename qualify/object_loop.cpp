// `lidar-qualify loop objects`: the two-fold cross-fit loop (see objects.h).
#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <optional>
#include <set>

#include "common/error.h"
#include "qualify/object_candidates.h"
#include "qualify/object_distribution.h"
#include "qualify/object_false_positives.h"
#include "qualify/object_folds.h"
#include "qualify/object_simulated.h"
#include "qualify/object_terms.h"
#include "qualify/objects.h"
#include "qualify/report.h"
#include "sensor/kpi_manager.h"

namespace fs = std::filesystem;

namespace lidarsim::qualify {

using namespace obj;

namespace {

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

}  // namespace

nlohmann::json loop_objects(const TrackingData& data, const LoopOptions& options) {
  const int nseq = static_cast<int>(data.calib.size());
  if (nseq < 2) throw Error("loop objects: need at least two sequences (one to fit, one held out), got " +
                            std::to_string(nseq));
  // Two-fold cross-fit: fold 1 fits on the even-indexed sequences and judges the odd-indexed ones,
  // fold 2 the other way round, so every sequence is held out once and judged by a model that
  // never saw it. With few sequences one split judges on too few tracks to tell an effect from
  // the track-to-track spread (on KITTI: 107 tracks, 3 of which hold a third of the error).
  // With at most kTimeFoldsMaxSequences sequences, the features fixed to the sensor are judged on
  // a second cross-fit whose folds are blocks of time within each sequence (tracks kept whole):
  // fold 1 fits the even blocks of every sequence and judges the odd ones, fold 2 the other way
  // round. Every other feature, and the false positives, keep the folds of whole sequences.
  std::vector<int> even, odd, all;
  for (int s = 0; s < nseq; ++s) (s % 2 == 0 ? even : odd).push_back(s), all.push_back(s);
  const sensor::FitOptions opt;
  std::vector<std::unique_ptr<FoldSet>> sets;
  sets.push_back(std::make_unique<FoldSet>());
  sets[0]->scheme = "sequences";
  sets[0]->data = &data;
  build_fold_set(*sets[0], {even, odd}, options, opt);
  if (nseq <= kTimeFoldsMaxSequences) {
    sets.push_back(std::make_unique<FoldSet>());
    FoldSet& T = *sets[1];
    T.scheme = "time blocks";
    T.time = split_into_time_blocks(data, kTimeBlocks, opt);
    T.data = &T.time.data;
    build_fold_set(T, time_block_sides(T.time), options, opt);
  }
  auto set_of = [&](int feature) { return sets.size() > 1 && fixed_to_sensor(kObjectFeatures[feature]) ? 1 : 0; };
  const std::array<Fold, 2>& folds = sets[0]->folds;  // whole sequences: the false positives' folds
  const int nvis = folds[0].base.visibility_bins();
  auto non_empty = [](const BlockSums& s) {
    BlockSums out;
    for (const auto& b : s)
      if (b[2] > 0) out.push_back(b);
    return out;
  };

  // Every candidate effect: each feature x target x form (object_candidates.h), judged on the
  // held-out folds. Bias forms (mean and rate) are ranked first; a spread form is added only when
  // no bias form is: an unmodelled bias makes the spread around the model's mean look
  // feature-dependent, so the spread is tested again on the next run with the bias in the model.
  std::vector<Candidate> cands;
  for (size_t f = 0; f < kObjectFeatures.size(); ++f)
    for (int t = 0; t < kObjectTargetCount; ++t) {
      const FoldSet& S = *sets[set_of(static_cast<int>(f))];
      bool enough = true;
      for (const Fold& k : S.folds) enough &= k.fit_r[t].r.size() >= 20 && k.held_r[t].r.size() >= 20;
      if (!enough) continue;
      const std::array<std::vector<int>, 2> blocks_t = {S.block[0][t], S.block[1][t]};
      for (Kind kind : kinds_for(t)) {
        Candidate c = judge_candidate(S.folds, t, static_cast<int>(f), kind, nvis, options.bins, blocks_t, S.nblocks);
        c.fold_set = set_of(static_cast<int>(f));
        c.undecided = cannot_decide(S, c);
        cands.push_back(std::move(c));
      }
    }
  // A feature's entry in a ranking: its best candidate of the forms asked for, among those the base
  // model already conditions on (used) or among the others (ranked).
  auto best_per_feature = [&](bool spread, bool used) {
    std::vector<const Candidate*> out;
    for (size_t f = 0; f < kObjectFeatures.size(); ++f) {
      const Candidate* best = nullptr;
      for (const Candidate& c : cands)
        if (c.feature == static_cast<int>(f) && is_spread(c.kind) == spread && used_by_model(c) == used &&
            (!best || c.score > best->score))
          best = &c;
      if (best) out.push_back(best);
    }
    std::sort(out.begin(), out.end(), [](const Candidate* a, const Candidate* b) { return a->score > b->score; });
    return out;
  };
  const auto ranking = best_per_feature(false, false), used = best_per_feature(false, true),
             spread_ranking = best_per_feature(true, false);
  nlohmann::json matrix = nlohmann::json::object(), spread_matrix = nlohmann::json::object();
  for (const Candidate& c : cands) {
    auto& m = is_spread(c.kind) ? spread_matrix : matrix;
    const std::string& fn = kObjectFeatures[c.feature];
    const std::string& tn = kObjectTargets[c.target];
    if (!m[fn].contains(tn) || m[fn][tn].get<double>() < c.score) m[fn][tn] = c.score;
  }
  if (ranking.empty()) throw Error("loop objects: too few matched objects to score any feature");

  // One bias candidate judged for adding: its refit per fold, the held-out residuals before and
  // after, and the block-bootstrap interval of the change.
  struct Judged {
    std::array<Refit, 2> refs;
    std::vector<double> before_r, after_r;
    std::array<std::pair<double, double>, 2> fold_rms{};
    std::array<double, 2> change{0, 0};
    int tracks = 0, tracks_better = 0;
    bool candidate = false, add = false;
    double candidate_after = kNaN;
    // Error targets: the re-simulated held-out distribution per class before / after the term
    // (-1: too few samples) and the classes that keep it.
    std::array<double, 3> dist_before{-1, -1, -1}, dist_after{-1, -1, -1};
    std::array<bool, 3> classes{true, true, true};
    std::array<std::pair<double, double>, 3> class_rms{};  // winsorised held-out RMS before, after
    bool distribution_rejected = false;
  };
  auto in_manager = [](const std::string& feature) {
    return std::find(sensor::kConditionalFeatures.begin(), sensor::kConditionalFeatures.end(), feature) !=
           sensor::kConditionalFeatures.end();
  };
  // Each fold's model with the terms added so far (FoldSet::current), for the distribution check.
  // Its seeds: seed + 100, + 101, ... (the qualification's held-out table uses seed + 1000 q).
  const std::uint64_t dist_seed = options.seed + 100;
  auto judge_add = [&](const Candidate& c, bool distribution_decides) {
    Judged J;
    const int t = c.target, f = c.feature;
    FoldSet& S = *sets[c.fold_set];
    const std::array<Fold, 2>& folds = S.folds;
    const auto& block = S.block;
    const size_t nblocks = S.nblocks;
    std::array<sensor::KpiModel, 2>& current = S.current;
    J.candidate = c.score >= options.threshold;
    J.refs = {fit_effect(folds[0], t, f, c.kind, nvis, options.bins).bias,
              fit_effect(folds[1], t, f, c.kind, nvis, options.bins).bias};
    // Held-out residuals before and after (each fold's own refit), and per track the winsorised
    // sums the acceptance test uses.
    BlockSums change_sums(nblocks, {0, 0, 0});  // per track: (sum after^2, sum before^2, n), winsorised
    std::array<std::array<double, 3>, 3> class_sums{};  // the same per class
    for (int k = 0; k < 2; ++k) {
      const Split& h = folds[k].held_r[t];
      const auto xh = h.column(f);
      const auto ch = h.classes(), bh = h.cells(t, nvis);
      std::vector<double> a(h.r.size());
      for (size_t i = 0; i < h.r.size(); ++i) {
        // Detection: the probability as the KPI manager will clamp it; errors: the table's mean.
        const double fitted =
            t == kDetectionTarget
                ? refit_probability(J.refs[k], ch[i], bh[i], xh[i], h.rec[i]->value[t] - h.r[i]) -
                      (h.rec[i]->value[t] - h.r[i])
                : J.refs[k](ch[i], bh[i], xh[i]);
        a[i] = h.r[i] - fitted;
        auto& s = change_sums[block[k][t][i]];
        if (t == kDetectionTarget) {
          const double y = h.rec[i]->value[t], p = y - h.r[i];
          s[0] += deviance(y, p + fitted), s[1] += deviance(y, p), s[2] += 1;  // p + fitted: clamped above
        } else {
          const double before_w = folds[k].win[t](h.r[i]), after_w = before_w - fitted;
          s[0] += after_w * after_w, s[1] += before_w * before_w, s[2] += 1;
          if (ch[i] >= 0 && ch[i] < 3) {
            auto& cs = class_sums[ch[i]];
            cs[0] += after_w * after_w, cs[1] += before_w * before_w, cs[2] += 1;
          }
        }
      }
      J.fold_rms[k] = {rms(h.r), rms(a)};
      J.before_r.insert(J.before_r.end(), h.r.begin(), h.r.end());
      J.after_r.insert(J.after_r.end(), a.begin(), a.end());
    }
    // Added only if the refit lowers the held-out RMS beyond the track-to-track noise: block
    // bootstrap 95% interval of the change below 0 (as the intensity loop does over scan sectors),
    // on the winsorised residuals the score used, so that a few tracks with gross errors cannot
    // decide it alone.
    if (J.candidate) {
      const BlockSums used_blocks = non_empty(change_sums);
      J.tracks = static_cast<int>(used_blocks.size());
      for (const auto& s : used_blocks) J.tracks_better += s[0] < s[1];
      // Detection: the change of the deviance per object; errors: of the winsorised RMS.
      J.change = t == kDetectionTarget
                     ? block_bootstrap_interval(used_blocks, [](const std::array<double, 3>& s) {
                         return s[2] > 0 ? (s[0] - s[1]) / s[2] : 0.0;
                       })
                     : block_bootstrap_interval(used_blocks, [](const std::array<double, 3>& s) {
                         return s[2] > 0 ? std::sqrt(s[0] / s[2]) - std::sqrt(s[1] / s[2]) : 0.0;
                       });
    }
    J.add = J.candidate && J.change[1] < 0;
    // Error targets: the term stays only for the classes whose re-simulated held-out distribution
    // of the KPI does not get worse (the noise shrunk for the term, with_term_and_noise); none: rejected.
    // For the top effect it is reported only: where a term explains most of an error's spread (a
    // planted effect on the reference sensor), the shrunk noise misfits the class's shape and the
    // check would veto the very effect the loop is for (a noise refit with the term is the missing piece).
    if (J.add && t != kDetectionTarget && in_manager(kObjectFeatures[f])) {
      std::array<sensor::KpiModel, 2> after_models;
      for (int k = 0; k < 2; ++k)
        after_models[k] = with_term_and_noise(current[k], J.refs[k], t, kObjectFeatures[f], nvis, folds[k].fit_r[t],
                                              folds[k].win[t]);
      const auto before_i = held_out_intersections_all(*S.data, folds, current, dist_seed, options.distribution_seeds);
      const auto after_i =
          held_out_intersections_all(*S.data, folds, after_models, dist_seed, options.distribution_seeds);
      J.dist_before = before_i[t], J.dist_after = after_i[t];
      // Pooled over both folds: on one fold alone a small class holds too few tracks to judge. The
      // class's own held-out residual must go down too: the re-simulated distribution carries
      // Monte Carlo noise of the size of the changes judged, the residual none.
      bool any = false;
      for (int c = 0; c < 3; ++c) {
        J.class_rms[c] = {class_sums[c][2] > 0 ? std::sqrt(class_sums[c][1] / class_sums[c][2]) : kNaN,
                          class_sums[c][2] > 0 ? std::sqrt(class_sums[c][0] / class_sums[c][2]) : kNaN};
        J.classes[c] = J.dist_after[c] >= 0 && J.dist_after[c] >= J.dist_before[c] &&
                       class_sums[c][0] < class_sums[c][1];
        any |= J.classes[c];
      }
      if (!distribution_decides) J.classes = {true, true, true};
      else if (!any) J.add = false, J.distribution_rejected = true;
    }
    J.candidate_after = rms(J.after_r);
    if (!J.add) J.after_r = J.before_r;
    return J;
  };

  const Candidate& top = *ranking.front();
  const int t = top.target, f = top.feature;
  const FoldSet& top_set = *sets[top.fold_set];
  const std::string top_feature = kObjectFeatures[f], top_target = kObjectTargets[t];
  Judged top_j = judge_add(top, false);
  const bool candidate = top_j.candidate, add = top_j.add;
  const std::array<Refit, 2>& refs = top_j.refs;
  const std::vector<double>& before_r = top_j.before_r;
  const std::vector<double>& after_r = top_j.after_r;
  const auto& fold_rms = top_j.fold_rms;
  const std::array<double, 2> change = top_j.change;
  const int tracks = top_j.tracks, tracks_better = top_j.tracks_better;
  const double candidate_after = top_j.candidate_after;

  // Only features the KPI manager can compute become a term; otherwise the model stays the base.
  std::string not_in_model;
  if (!add) not_in_model = "no effect added";
  else if (std::find(sensor::kConditionalFeatures.begin(), sensor::kConditionalFeatures.end(), top_feature) ==
           sensor::kConditionalFeatures.end())
    not_in_model = "the KPI manager cannot compute \"" + top_feature + "\" from a truth object";
  const bool term = not_in_model.empty();
  // An added term goes into each fold's current model (the noise refitted with it for an error), in
  // every fold set: refitted on that set's folds where it was judged on the other one.
  auto add_to_current = [&](const Judged& J, const Candidate& c) {
    const int te = c.target;
    const std::string& fe = kObjectFeatures[c.feature];
    for (size_t q = 0; q < sets.size(); ++q) {
      FoldSet& S = *sets[q];
      for (int k = 0; k < 2; ++k) {
        const Refit r = static_cast<int>(q) == c.fold_set
                            ? J.refs[k]
                            : fit_effect(S.folds[k], te, c.feature, c.kind, nvis, options.bins).bias;
        S.current[k] = te == kDetectionTarget
                           ? with_term(S.current[k], r, te, fe, nvis)
                           : with_term_and_noise(S.current[k], r, te, fe, nvis, S.folds[k].fit_r[te],
                                                 S.folds[k].win[te], J.classes);
      }
    }
  };
  if (term) add_to_current(top_j, top);

  // Greedy over targets: with the top bias form added as a term, the best bias form of every other
  // target (of the features the KPI manager can compute, in a form the base model does not hold
  // already: used_by_model) is judged the same way, in order of
  // score, at most one per target; each must clear the threshold and the block-bootstrap change
  // test on its own. A term on one target leaves the other targets' residuals unchanged, and the
  // KPI model holds one conditional term per target, so each is judged against the base alone.
  struct Extra {
    const Candidate* c;
    Judged j;
  };
  std::vector<Extra> extras;
  std::vector<const Candidate*> extra_rejected;
  std::vector<bool> extra_rejected_by_distribution;
  if (term) {
    std::array<const Candidate*, kObjectTargetCount> best_t{};
    for (const Candidate& c : cands)
      if (!is_spread(c.kind) && c.target != t && !used_by_model(c) &&
          in_manager(kObjectFeatures[c.feature]) && (!best_t[c.target] || c.score > best_t[c.target]->score))
        best_t[c.target] = &c;
    std::vector<const Candidate*> order;
    for (const Candidate* c : best_t)
      if (c && c->score >= options.threshold) order.push_back(c);
    std::sort(order.begin(), order.end(), [](const Candidate* a, const Candidate* b) { return a->score > b->score; });
    for (const Candidate* c : order) {
      if (options.max_effects > 0 && 1 + static_cast<int>(extras.size()) >= options.max_effects) break;
      Judged J = judge_add(*c, true);
      if (J.add) add_to_current(J, *c), extras.push_back({c, std::move(J)});
      else extra_rejected.push_back(c), extra_rejected_by_distribution.push_back(J.distribution_rejected);
    }
  }

  // No bias form added: the best spread form is, if it clears the threshold, its score's block-bootstrap
  // interval lies above 0 and the KPI manager can compute its feature.
  const Candidate* sp = !add && !spread_ranking.empty() ? spread_ranking.front() : nullptr;
  const bool add_spread =
      sp && sp->score >= options.threshold && sp->interval[0] > 0 &&
      std::find(sensor::kConditionalFeatures.begin(), sensor::kConditionalFeatures.end(),
                kObjectFeatures[sp->feature]) != sensor::kConditionalFeatures.end();
  double spread_before_sim = kNaN, spread_after_sim = kNaN;
  std::array<std::pair<double, double>, 2> spread_fold{};
  if (add_spread) {
    // Re-simulated: per held-out object one draw of the error with each fold's base and refitted
    // model, centred on the base's conditional mean; measured errors centred the same way; both
    // winsorised at the fold's fit limits. Spread error of the draws against the measured errors.
    const int st = sp->target, sf = sp->feature;
    const FoldSet& S = *sets[sp->fold_set];
    const auto& motion = S.motion;
    std::vector<double> sx, sm, sb, sa;
    for (int k = 0; k < 2; ++k) {
      const Fold& fd = S.folds[k];
      const Effect e = fit_effect(fd, st, sf, sp->kind, nvis, options.bins);
      const Losses L = held_losses(fd, e, nvis);
      spread_fold[k] = {spread_error(L.x, L.centred, L.sd_before), spread_error(L.x, L.centred, L.sd_after)};
      const sensor::KpiModel refitted = with_spread_term(fd.base, e, kObjectFeatures[sf]);
      const auto mean = simulated_mean_error(motion, fd.held_idx, fd.base, kTargetParam[st], options.seed);
      const auto db = simulated_error_draw(motion, fd.held_idx, fd.base, kTargetParam[st], options.seed);
      const auto da = simulated_error_draw(motion, fd.held_idx, refitted, kTargetParam[st], options.seed);
      const Winsor& w = fd.win[st];
      for (const ObjectRecord* r : fd.held_r[st].rec) {
        const std::array<int, 3> key{r->seq, r->frame, r->track};
        const auto im = mean.find(key), ib = db.find(key), ia = da.find(key);
        if (im == mean.end() || ib == db.end() || ia == da.end()) continue;
        sx.push_back(r->feature[sf]);
        sm.push_back(w(r->value[st] - im->second));
        sb.push_back(std::abs(w(ib->second) - im->second));
        sa.push_back(std::abs(w(ia->second) - im->second));
      }
    }
    if (!sx.empty()) spread_before_sim = spread_error(sx, sm, sb), spread_after_sim = spread_error(sx, sm, sa);
  }

  // The same RMS with what the KPI manager really uses per held-out truth object — the
  // conditional mean error (noise off) or the detection probability — with each fold's base and
  // refitted model; truth motion by differences, as the features the term was fitted on.
  // Every added term's target, re-simulated with the model that carries all of them.
  // Each on the fold set it was judged on.
  std::vector<const Candidate*> sim_cands{&top};
  for (const Extra& e : extras) sim_cands.push_back(e.c);
  std::vector<double> sim_before(sim_cands.size(), kNaN), sim_after(sim_cands.size(), kNaN);
  {
    std::vector<std::vector<double>> rb(sim_cands.size()), ra(sim_cands.size());
    for (int k = 0; k < 2; ++k) {
      for (size_t q = 0; q < sim_cands.size(); ++q) {
        const FoldSet& S = *sets[sim_cands[q]->fold_set];
        const auto& motion = S.motion;
        const Fold& fd = S.folds[k];
        const sensor::KpiModel& refitted = S.current[k];  // every added term
        const int tq = sim_cands[q]->target;
        std::map<std::array<int, 3>, double> mb, ma;
        if (tq == kDetectionTarget) {
          mb = simulated_detection_probability(motion, fd.held_idx, fd.base, options.seed);
          ma = simulated_detection_probability(motion, fd.held_idx, refitted, options.seed);
        } else {
          mb = simulated_mean_error(motion, fd.held_idx, fd.base, kTargetParam[tq], options.seed);
          ma = simulated_mean_error(motion, fd.held_idx, refitted, kTargetParam[tq], options.seed);
        }
        for (const ObjectRecord* r : fd.held_r[tq].rec) {
          const auto ib = mb.find({r->seq, r->frame, r->track}), ia = ma.find({r->seq, r->frame, r->track});
          if (ib == mb.end() || ia == ma.end()) continue;
          rb[q].push_back(r->value[tq] - ib->second);
          ra[q].push_back(r->value[tq] - ia->second);
        }
      }
    }
    for (size_t q = 0; q < sim_cands.size(); ++q)
      if (!rb[q].empty()) sim_before[q] = rms(rb[q]), sim_after[q] = rms(ra[q]);
  }
  const double before_sim = sim_before[0], after_sim = sim_after[0];

  // The model to use from now on: base and term fitted on every sequence.
  Fold whole;
  whole.pool_track_spread = options.pool_track_spread;
  make_fold(whole, data, all, {}, opt);
  whole.shrink_terms = options.shrink_terms;
  const Refit final_ref = fit_effect(whole, t, f, top.kind, nvis, options.bins).bias;
  std::optional<Effect> final_spread;
  if (add_spread) final_spread = fit_effect(whole, sp->target, sp->feature, sp->kind, nvis, options.bins);
  sensor::KpiModel final_term_model;
  if (term) {
    // Each term with the noise shrunk for it, for the classes that kept it.
    auto add_final = [&](const Refit& r, int te, const std::string& fe, const std::array<bool, 3>& classes) {
      final_term_model = te == kDetectionTarget ? with_term(final_term_model, r, te, fe, nvis)
                                                : with_term_and_noise(final_term_model, r, te, fe, nvis, whole.fit_r[te],
                                                                      whole.win[te], classes);
    };
    final_term_model = whole.base;
    add_final(final_ref, t, top_feature, top_j.classes);
    for (const Extra& e : extras)
      add_final(fit_effect(whole, e.c->target, e.c->feature, e.c->kind, nvis, options.bins).bias, e.c->target,
                kObjectFeatures[e.c->feature], e.j.classes);
  }
  // False positives: their own outcome and stream, judged apart from the error and detection terms.
  const FpAnalysis fpa = analyse_false_positives(data, folds, options.threshold, options.bins, options.seed);
  if (!options.out_model.empty()) {
    sensor::KpiModel out = term         ? final_term_model
                           : add_spread ? with_spread_term(whole.base, *final_spread, kObjectFeatures[sp->feature])
                                        : whole.base;
    if (fpa.added >= 0) out = with_fitted_fp_table(out, whole, fpa.candidates[fpa.added], options.bins);
    if (fpa.persistence.added) out = with_fp_persistence(out, data, whole.fit_idx, whole.fit_set, options.seed);
    sensor::save_kpi_model(out, options.out_model);
  }

  std::string plot;
  if (!options.plots_dir.empty()) {
    // Fold 1's held-out residuals against the table fitted on its fit sequences.
    plot = "residual_" + top_target + "_vs_" + top_feature + ".png";
    fs::create_directories(options.plots_dir);
    const Split& h = top_set.folds[0].held_r[t];
    write_residual_png(options.plots_dir / plot, refs[0].table.pooled, h.column(f), h.r,
                       {"Held-out " + top_target + " residual vs " + top_feature + " (fold 1)",
                        feature_axis_label(top_feature),
                        top_target + " residual, measured - model " + target_unit(top_target)});
  }

  nlohmann::json j;
  j["domain"] = "objects";
  j["metric"] = "held-out RMS residual of " + top_target +
                (t == kDetectionTarget ? " (detected 0/1 minus the model's detection probability)"
                                       : " (measured error minus the model's conditional mean error)") +
                ", both folds of the cross-fit";
  j["before"] = rms(before_r);
  j["after"] = rms(after_r);
  // The same RMS with what the KPI manager uses (base model / refitted model).
  j["before_simulated"] = std::isnan(before_sim) ? nlohmann::json(nullptr) : nlohmann::json(before_sim);
  j["after_simulated"] = std::isnan(after_sim) ? nlohmann::json(nullptr) : nlohmann::json(after_sim);
  j["model_term"] = term ? nlohmann::json(top_feature) : nlohmann::json(nullptr);
  if (term) j["model_term_on"] = t == kDetectionTarget ? "detection_probability" : "errors." + top_target;
  if (!term) j["model_term_absent_because"] = not_in_model;
  if (!options.out_model.empty()) j["out_model"] = options.out_model.string();
  auto ranked = [](const std::vector<const Candidate*>& list) {
    nlohmann::json out = nlohmann::json::array();
    for (const Candidate* c : list)
      out.push_back({{"feature", kObjectFeatures[c->feature]}, {"score", c->score},
                     {"target", kObjectTargets[c->target]}, {"kind", to_string(c->kind)}, {"interval95", c->interval}});
    return out;
  };
  j["ranking"] = ranked(ranking);
  j["used_by_model"] = ranked(used);
  j["spread_ranking"] = ranked(spread_ranking);
  j["added_effect"] = add ? nlohmann::json(top_feature) : nlohmann::json(nullptr);
  if (candidate) {
    j["change_interval95"] = change;  // of the winsorised RMS
    j["held_out_tracks"] = tracks;
    j["held_out_tracks_better"] = tracks_better;
  }
  if (candidate && !add)
    j["rejected_effect"] = {
        {"feature", top_feature},
        {"target", top_target},
        {"held_out_after", candidate_after},
        {"change_interval95", change},
        {"why", top_j.distribution_rejected ? "the re-simulated held-out distribution of the KPI got worse for every class"
                : top.undecided.empty()         ? "the refit did not lower the held-out RMS beyond the track-to-track noise"
                                                : "the data cannot decide: " + top.undecided}};
  j["threshold"] = options.threshold;
  j["distribution_seeds"] = options.distribution_seeds;  // of the per-class distribution check
  j["score_definition"] =
      "every feature x target x form is a candidate (kinds: mean_table, mean_window on an error; rate_table, "
      "rate_window on detection; spread_table, spread_window on an error's sigma). Each is fitted on a fold's fit "
      "sequences and scored on its held-out ones, pooled over the two-fold cross-fit (fit on the even-indexed "
      "sequences, judge the odd-indexed ones, and the other way round): mean forms by the held-out R^2 of the "
      "winsorised residual (measured - base model) against the fit split's mean; rate forms by the deviance R^2 "
      "1 - D_after / D_before (Bernoulli deviance with the model's detection probability); spread forms by "
      "1 - exp(-(G_before - G_after) / n) with G the Gaussian deviance around the fit split's per-class range-bin "
      "mean and sd. Tables: 10 equal-count bins on the fit split, shrunk by n/(n+5), per class where >= 200 "
      "samples; windows: the best contiguous run of 40 equal-count bins (a step when it touches an end). Bias forms "
      "are refitted with per-class range-bin (detection: range x visibility) offsets, 4 backfitting passes. "
      "interval95 = basic block bootstrap over held-out tracks (a track and its sequence are never on both sides). "
      "The top bias form is added when its score is at least the threshold and the refit lowers the held-out loss "
      "(winsorised RMS; detection: deviance) with a block-bootstrap 95% interval of the change below 0; each "
      "further bias form (the best of every other target) passes the same test and, on an error, is kept only for "
      "the classes whose re-simulated held-out distribution (histogram intersection of the KPI manager's errors, "
      "32 seeds, against the measured held-out errors, both folds pooled) does not get worse and whose own held-out "
      "residual falls (rejected when no class keeps it); if no bias form is added, "
      "the top spread form is added when its score is at least the threshold and its interval lies above 0. "
      "With at most 3 sequences the features fixed to the sensor (azimuth) are judged on folds of time blocks "
      "instead: each sequence cut into 4 blocks of its tracks by middle frame, fit on the even blocks and judge the "
      "odd ones, and the other way round. A candidate judged on one sequence per fold (a feature that can depend "
      "on the place) or on fewer than 10 held-out tracks in a fold is reported as \"the data cannot decide\" "
      "rather than ruled out or rejected";
  j["scores"] = matrix;
  j["spread_scores"] = spread_matrix;
  // Every candidate tested, with what became of it.
  nlohmann::json cj = nlohmann::json::array();
  for (const Candidate& c : cands) {
    std::string decision;
    const bool extra_added =
        std::any_of(extras.begin(), extras.end(), [&](const Extra& e) { return e.c == &c; });
    const auto tried = std::find(extra_rejected.begin(), extra_rejected.end(), &c);
    const bool extra_tried = tried != extra_rejected.end();
    const std::string by_distribution =
        "rejected: the re-simulated held-out distribution of the KPI got worse for every class";
    // No evidence for an effect is evidence against it only where the held-out data can decide.
    const std::string cannot = "the data cannot decide: " + c.undecided;
    const std::string by_noise =
        c.undecided.empty() ? "rejected: the refit did not beat the track-to-track noise" : cannot;
    if ((&c == &top && add) || extra_added) decision = "added";
    else if (extra_tried && extra_rejected_by_distribution[tried - extra_rejected.begin()]) decision = by_distribution;
    else if (extra_tried) decision = by_noise;
    else if (&c == &top && top_j.distribution_rejected) decision = by_distribution;
    else if (add_spread && &c == sp) decision = "added";
    else if (&c == &top && candidate) decision = by_noise;
    else if (used_by_model(c))
      decision = "not ranked: the base KPI model already conditions " + kObjectTargets[c.target] + " on " +
                 kObjectFeatures[c.feature] + " in this form";
    else if (!c.undecided.empty() && (c.score < options.threshold || c.interval[0] <= 0)) decision = cannot;
    else if (c.score < options.threshold) decision = "ruled out: held-out score below the threshold";
    else if (c.interval[0] <= 0) decision = "ruled out: interval reaches 0";
    else if (is_spread(c.kind) && add) decision = "not tried: a bias form was added first";
    else if (!is_spread(c.kind) && c.target != t && !in_manager(kObjectFeatures[c.feature]))
      decision = "not added: the KPI manager cannot compute \"" + kObjectFeatures[c.feature] +
                 "\" from a truth object, so it is added only as the top effect (without a model term)";
    else if (!is_spread(c.kind) && c.target != t && !term)
      decision = "not tried: further bias forms are tried only once the top one is a model term";
    else decision = "not added: at most one bias form per target is added per run, the best first";
    cj.push_back({{"target", kObjectTargets[c.target]},
                  {"feature", kObjectFeatures[c.feature]},
                  {"kind", to_string(c.kind)},
                  {"form_fold1", c.form},
                  {"effect_size", c.effect_size},
                  {"score", c.score},
                  {"interval95", c.interval},
                  {"significant", c.interval[0] > 0},
                  {"error_metric", is_spread(c.kind)              ? "spread error"
                                   : c.target == kDetectionTarget ? "deviance per object"
                                                                  : "RMS residual"},
                  {"error_before", c.error_before},
                  {"error_after", c.error_after},
                  {"held_out_objects", c.n},
                  {"folds", sets[c.fold_set]->scheme},
                  {"decision", decision}});
  }
  j["candidates"] = cj;
  j["false_positives"] = fp_json(fpa, options.threshold);
  if (!options.plots_dir.empty() && j["false_positives"].contains("persistence")) {
    auto& p = j["false_positives"]["persistence"];
    fs::create_directories(options.plots_dir);
    p["plot_caption"] = write_fp_tracks_png(options.plots_dir / "fp_track_lengths.png", p);
    p["plot"] = "fp_track_lengths.png";
  }
  j["error_metric"] = t == kDetectionTarget ? "deviance per object" : "RMS residual";
  j["error_before"] = top.error_before;
  j["error_after"] = add ? top.error_after : top.error_before;
  j["added_kind"] = add ? nlohmann::json(to_string(top.kind)) : nlohmann::json(nullptr);
  if (add_spread) {
    const std::string sf = kObjectFeatures[sp->feature], stn = kObjectTargets[sp->target];
    j["metric"] = "held-out spread error of " + stn +
                  ": in 10 equal-count bins of " + sf + ", log(measured sd / model sd), RMS over bins; both folds";
    j["before"] = sp->error_before;
    j["after"] = sp->error_after;
    j["error_metric"] = "spread error";
    j["error_before"] = sp->error_before;
    j["error_after"] = sp->error_after;
    j["before_simulated"] = std::isnan(spread_before_sim) ? nlohmann::json(nullptr) : nlohmann::json(spread_before_sim);
    j["after_simulated"] = std::isnan(spread_after_sim) ? nlohmann::json(nullptr) : nlohmann::json(spread_after_sim);
    j["added_effect"] = sf;
    j["added_kind"] = to_string(sp->kind);
    j["model_term"] = sf;
    j["model_term_on"] = "errors." + stn + ".scale";
    j.erase("model_term_absent_because");
    j["effect"] = {{"feature", sf},
                   {"target", stn},
                   {"kind", to_string(sp->kind) + ": the error's sigma x scale per bin, pooled over classes, fitted on "
                                                  "every sequence"},
                   {"edges", final_spread->scale.edges},
                   {"scale", final_spread->scale.value}};
  }
  if (add) {
    const ClassTables& tab = final_ref.table;
    nlohmann::json e = {{"feature", top_feature},
                        {"target", top_target},
                        {"kind", to_string(top.kind) +
                                     (is_window(top.kind)
                                          ? ": one bias inside a window of the feature with fitted edges (pooled over "
                                            "classes), refitted jointly with per-class range-bin offsets on every sequence"
                                          : ": per-class per-bin bias table (pooled for classes with < 200 fit "
                                            "samples), refitted jointly with per-class range-bin offsets on every "
                                            "sequence")},
                        {"pooled", {{"edges", tab.pooled.edges}, {"bias", tab.pooled.value}}}};
    for (int c = 0; c < 3; ++c)
      if (tab.own[c]) e[kObjectClasses[c]] = {{"edges", tab.per_class[c].edges}, {"bias", tab.per_class[c].value}};
    if (options.shrink_terms != TermShrink::Off) {  // per bin: the share of the fitted (deviation) kept
      e["pooled"]["shrink_factor"] = final_ref.factor.pooled.value;
      for (int c = 0; c < 3; ++c)
        if (tab.own[c]) e[kObjectClasses[c]]["shrink_factor"] = final_ref.factor.per_class[c].value;
    }
    j["effect"] = e;
  }
  // Every bias form added (the top one first), each with its own before -> after; the simulated
  // "after" is with the model that carries all of them.
  // Per class: re-simulated held-out histogram intersection before / after and whether it kept the term.
  auto distribution_entry = [&](const Judged& J) {
    nlohmann::json d = nlohmann::json::object();
    for (int c = 0; c < 3; ++c)
      if (J.dist_before[c] >= 0 || J.dist_after[c] >= 0)
        d[kObjectClasses[c]] = {{"before", J.dist_before[c]},
                                {"after", J.dist_after[c]},
                                {"rms_before", J.class_rms[c].first},
                                {"rms_after", J.class_rms[c].second},
                                {"kept", J.classes[c]}};
    return d;
  };
  nlohmann::json aj = nlohmann::json::array();
  // Each fold's shrink factors per bin (pooled, then the classes with their own table); null when not shrunk.
  auto shrink_entry = [&](const Judged& J) {
    if (options.shrink_terms == TermShrink::Off) return nlohmann::json(nullptr);
    nlohmann::json out = nlohmann::json::array();
    for (const Refit& r : J.refs) {
      nlohmann::json f = {{"pooled", {{"factor", r.factor.pooled.value}, {"se", r.se.pooled.value}}}};
      for (int c = 0; c < 3; ++c)
        if (r.factor.own[c])
          f[kObjectClasses[c]] = {{"factor", r.factor.per_class[c].value}, {"se", r.se.per_class[c].value}};
      out.push_back(f);
    }
    return out;
  };
  auto added_entry = [&](const Candidate& c, const Judged& J, double sb, double sa) {
    return nlohmann::json{{"feature", kObjectFeatures[c.feature]},
                          {"shrink_per_fold", shrink_entry(J)},
                          {"target", kObjectTargets[c.target]},
                          {"kind", to_string(c.kind)},
                          {"score", c.score},
                          {"model_term_on", c.target == kDetectionTarget ? "detection_probability"
                                                                          : "errors." + kObjectTargets[c.target]},
                          {"before", rms(J.before_r)},
                          {"after", rms(J.after_r)},
                          {"before_simulated", std::isnan(sb) ? nlohmann::json(nullptr) : nlohmann::json(sb)},
                          {"after_simulated", std::isnan(sa) ? nlohmann::json(nullptr) : nlohmann::json(sa)},
                          {"change_interval95", J.change},
                          {"held_out_tracks", J.tracks},
                          {"held_out_tracks_better", J.tracks_better},
                          {"distribution", distribution_entry(J)},
                          {"distribution_decides", &c != &top}};  // the top effect's is reported only
  };
  if (add) aj.push_back(added_entry(top, top_j, before_sim, after_sim));
  for (size_t q = 0; q < extras.size(); ++q)
    aj.push_back(added_entry(*extras[q].c, extras[q].j, sim_before[q + 1], sim_after[q + 1]));
  j["added_effects"] = aj;
  nlohmann::json fj = nlohmann::json::array();
  for (int k = 0; k < 2; ++k)
    fj.push_back({{"fit_sequences", names_of(*top_set.data, top_set.folds[k].fit_idx)},
                  {"held_out_sequences", names_of(*top_set.data, top_set.folds[k].held_idx)},
                  {"before", fold_rms[k].first},
                  {"after", add ? fold_rms[k].second : fold_rms[k].first}});
  if (add_spread)
    for (int k = 0; k < 2; ++k) fj[k]["before"] = spread_fold[k].first, fj[k]["after"] = spread_fold[k].second;
  j["folds"] = fj;  // of the top effect's fold set
  j["fold_scheme"] = top_set.scheme;
  if (sets.size() > 1)
    j["time_folds"] = {{"features", kSensorFixedFeatures},
                       {"blocks_per_sequence", kTimeBlocks},
                       {"why", std::to_string(nseq) + " sequences: the features fixed to the sensor are judged on blocks "
                                                      "of time within each sequence (tracks kept whole), the others "
                                                      "on whole sequences"}};
  j["held_out_samples"] = before_r.size();
  if (options.pool_track_spread) {
    nlohmann::json tj = nlohmann::json::object();  // track_std after / before, per class: length, width, height
    for (int c = 0; c < 3; ++c)
      if (c < static_cast<int>(whole.track_spread_factor.size())) tj[kObjectClasses[c]] = whole.track_spread_factor[c];
    j["track_spread_pooling"] = tj;
  }
  if (!plot.empty()) j["plot"] = plot;
  return j;
}

}  // namespace lidarsim::qualify
