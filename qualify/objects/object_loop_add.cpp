// The object loop's add step (object_loop.h): the top bias form, then the best bias form of each
// other target, else the best spread form; each decision recorded with its reason as it is made,
// and at the end why every candidate left over was not tried.
#include <algorithm>

#include "qualify/objects/object_loop.h"
#include "qualify/objects/object_spread_forms.h"
#include "qualify/report.h"

namespace lidarsim::qualify::obj {

namespace {

std::string name_of(const Candidate& c) {
  return kObjectFeatures[c.feature] + " " + to_string(c.kind) + " on " + kObjectTargets[c.target] + " (score " +
         fmt(c.score, 3) + ")";
}

std::string interval_text(const std::array<double, 2>& v) { return "[" + fmt(v[0], 4) + ", " + fmt(v[1], 4) + "]"; }

// The loss whose change the bootstrap judges (Judged::change).
std::string loss_of(const Candidate& c) {
  return c.target == kDetectionTarget ? "deviance per object" : "winsorised RMS residual";
}

std::string tracks_text(const Judged& J) {
  return "better on " + std::to_string(J.tracks_better) + " of " + std::to_string(J.tracks) + " held-out tracks";
}

Decision added(const Candidate& c, const Judged& J, const std::string& note) {
  return {DecisionKind::Added, "added: the refit lowers the held-out RMS residual of " + kObjectTargets[c.target] +
                                   " from " + fmt(rms(J.before_r), 4) + " to " + fmt(J.candidate_after, 4) +
                                   "; 95 % interval of the change of the " + loss_of(c) + " " +
                                   interval_text(J.change) + ", below 0; " + tracks_text(J) + note};
}

Decision rejected(const Candidate& c, const Judged& J) {
  if (!c.undecided.empty())
    return {DecisionKind::CannotDecide, "the data cannot decide: " + c.undecided + " (the refit's change of the " +
                                            loss_of(c) + " " + interval_text(J.change) + " reaches 0)"};
  return {DecisionKind::RejectedByNoise,
          "not added: the refit changes the held-out " + loss_of(c) + " by " + interval_text(J.change) +
              " (95 % interval), which reaches 0: no more than the track-to-track noise; " + tracks_text(J) +
              "; more sequences would tell"};
}

Decision rejected_by_distribution(const Candidate& c, const Judged& J) {
  std::string per_class;
  for (int k = 0; k < kObjectClassCount; ++k) {
    if (J.dist_before[k] < 0 && J.dist_after[k] < 0) continue;
    per_class += (per_class.empty() ? "" : "; ") + kObjectClasses[k] + ": ";
    if (J.dist_after[k] < 0) per_class += "too few held-out samples to re-simulate";
    else if (J.dist_after[k] < J.dist_before[k])
      per_class += "histogram intersection " + fmt(J.dist_before[k], 3) + " -> " + fmt(J.dist_after[k], 3);
    else
      per_class += "held-out RMS " + fmt(J.class_rms[k].first, 4) + " -> " + fmt(J.class_rms[k].second, 4);
  }
  return {DecisionKind::RejectedByDistribution,
          "not added: with it the KPI manager's re-simulated held-out " + kObjectTargets[c.target] +
              " errors match the measured ones worse, or the class's held-out residual does not fall, for every "
              "class (" + per_class + ")"};
}

// The classes a further error term was kept for, when not all.
std::string kept_for(const Candidate& c, const Judged& J) {
  if (c.target == kDetectionTarget || std::all_of(J.classes.begin(), J.classes.end(), [](bool kept) { return kept; })) return "";
  std::string kept, dropped;
  for (int k = 0; k < kObjectClassCount; ++k) {
    std::string& list = J.classes[k] ? kept : dropped;
    list += (list.empty() ? "" : ", ") + kObjectClasses[k];
  }
  return "; kept for " + kept + " only (for " + dropped +
         " the re-simulated distribution or the class's held-out residual got worse)";
}

// An added term goes into each fold's current model (the noise refitted with it for an error), in
// every fold set: refitted on that set's folds where it was judged on the other one.
void add_to_current(LoopContext& L, const Judged& J, const Candidate& c) {
  const int te = c.target;
  const std::string& fe = kObjectFeatures[c.feature];
  for (size_t q = 0; q < L.sets.size(); ++q) {
    FoldSet& S = *L.sets[q];
    for (int k = 0; k < 2; ++k) {
      const Refit r = static_cast<int>(q) == c.fold_set
                          ? J.refs[k]
                          : fit_effect(S.folds[k], te, c.feature, c.kind, L.nvis, L.options.bins).bias;
      S.current[k] = te == kDetectionTarget ? with_term(S.current[k], r, te, fe, L.nvis)
                                            : with_term_and_noise(S.current[k], r, te, fe, L.nvis,
                                                                  S.folds[k].fit_r[te], S.folds[k].win[te], J.classes);
    }
  }
}

// The top bias form: judged as every further one is (judge); a model term when the KPI manager
// computes its feature, else added to the report only.
void add_top(LoopContext& L, ObjectLoopResult& R) {
  const Candidate& top = R.candidates[R.top];
  R.top_judged = judge(L, top);
  const Judged& J = R.top_judged;
  if (!J.add) R.not_a_term = "no effect added";
  else if (!in_manager(kObjectFeatures[top.feature]))
    R.not_a_term = "the KPI manager cannot compute \"" + kObjectFeatures[top.feature] + "\" from a truth object";
  if (J.add) {
    R.decisions[R.top] = added(top, J, (R.term() ? "" : "; not a model term: " + R.not_a_term) + kept_for(top, J));
    R.added.push_back({R.top, J, kNaN, kNaN});
  } else if (J.candidate) {
    R.decisions[R.top] = J.distribution_rejected ? rejected_by_distribution(top, J) : rejected(top, J);
  }
  if (R.term()) add_to_current(L, J, top);
}

// The best bias form per other target, of the features the KPI manager computes, in a form the
// base model does not hold already (-1: none); those that pass the ranking's tests first.
std::array<int, kObjectTargetCount> best_further(const ObjectLoopResult& R) {
  std::array<int, kObjectTargetCount> best;
  best.fill(-1);
  const int t = R.top_candidate().target;
  for (size_t i = 0; i < R.candidates.size(); ++i) {
    const Candidate& c = R.candidates[i];
    if (!is_spread(c.kind) && c.target != t && !used_by_model(c) && in_manager(kObjectFeatures[c.feature]) &&
        (best[c.target] < 0 || ranks_before(c, R.candidates[best[c.target]], R.options.threshold)))
      best[c.target] = static_cast<int>(i);
  }
  return best;
}

// Greedy over targets: with the top bias form added as a term, the best further bias form of every
// other target is judged the same way, in order of score, at most one per target and max_effects
// in all; each must clear the threshold and the block-bootstrap change test on its own, and the
// distribution check decides as for the top one. A term on one target leaves the other targets' residuals unchanged,
// and the KPI model holds one conditional term per target, so each is judged against the base alone.
void add_further(LoopContext& L, ObjectLoopResult& R) {
  if (!R.term()) return;
  std::vector<int> order;
  for (int i : best_further(R))
    if (i >= 0 && R.candidates[i].score >= L.options.threshold && clears_selection(R.candidates[i]) &&
        line_over_table(R.candidates[i]))
      order.push_back(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return R.candidates[a].score > R.candidates[b].score; });
  for (int i : order) {
    const Candidate& c = R.candidates[i];
    if (L.options.max_effects > 0 && static_cast<int>(R.added.size()) >= L.options.max_effects) {
      if (R.decisions[i].kind == DecisionKind::Pending)
        R.decisions[i] = {DecisionKind::MaxEffects,
                          "not tried: at most " + std::to_string(L.options.max_effects) +
                              " bias forms are added per run (--max-effects " +
                              std::to_string(L.options.max_effects) +
                              "), and as many were added already; run the loop again on the model it writes to "
                              "test it"};
      continue;
    }
    Judged J = judge(L, c);
    if (J.add) {
      R.decisions[i] = added(c, J, kept_for(c, J));
      add_to_current(L, J, c);
      R.added.push_back({i, std::move(J), kNaN, kNaN});
    } else {
      R.decisions[i] = J.distribution_rejected ? rejected_by_distribution(c, J) : rejected(c, J);
    }
  }
}

// No bias form added: the best spread form is, if it clears the threshold, its score's
// block-bootstrap interval lies above 0 and the KPI manager can compute its feature.
void add_spread(const LoopContext& L, ObjectLoopResult& R) {
  if (R.top_added() || R.spread_ranking.empty()) return;
  const int first = R.spread_ranking.front();
  const Candidate& picked = R.candidates[first];
  if (picked.score < R.options.threshold || picked.interval[0] <= 0 || !clears_selection(picked)) return;
  const int i = best_form_of_picked(R.candidates, first, R.options.threshold);  // object_spread_forms.h
  const Candidate& sp = R.candidates[i];
  if (!in_manager(kObjectFeatures[sp.feature])) {
    R.decisions[i] = {DecisionKind::NotInManager, "not added: the KPI manager cannot compute \"" +
                                                      kObjectFeatures[sp.feature] +
                                                      "\" from a truth object, so a spread form on it cannot become "
                                                      "a model term"};
    return;
  }
  R.decisions[i] = {DecisionKind::Added, "added: the held-out spread error of " + kObjectTargets[sp.target] +
                                             " falls from " + fmt(sp.error_before, 4) + " to " +
                                             fmt(sp.error_after, 4) + "; score " + fmt(sp.score, 3) +
                                             " with 95 % interval " + interval_text(sp.interval) + " above 0" +
                                             (i == first ? std::string()
                                                         : "; the best form of " + kObjectFeatures[sp.feature] +
                                                               " on this target, whose " + name_of(picked) +
                                                               " clears the bound over the spread forms")};
  R.spread = AddedSpread{};
  R.spread->candidate = i;
  // The form's sigma per held-out record, before and after, as the candidate was judged.
  const FoldSet& S = L.set_of(sp);
  for (int k = 0; k < 2; ++k) {
    const Losses H = held_losses(S.folds[k], fit_effect(S.folds[k], sp.target, sp.feature, sp.kind, L.nvis,
                                                        L.options.bins), L.nvis);
    const Split& h = S.folds[k].held_r[sp.target];
    for (size_t r = 0; r < H.sd_before.size(); ++r) {
      R.spread->held_features.push_back(h.rec[r]->feature), R.spread->held_class.push_back(h.rec[r]->cls);
      R.spread->sd_before.push_back(H.sd_before[r]), R.spread->sd_after.push_back(H.sd_after[r]);
    }
  }
}

// Why each candidate still undecided (its score clears the threshold, its interval lies above 0)
// was not tried.
void settle_untried(ObjectLoopResult& R) {
  const Candidate& top = R.top_candidate();
  const std::array<int, kObjectTargetCount> further = best_further(R);
  const std::string again = "; run the loop again on the model it writes to test it";
  for (size_t i = 0; i < R.candidates.size(); ++i) {
    if (R.decisions[i].kind != DecisionKind::Pending) continue;
    const Candidate& c = R.candidates[i];
    const std::string& fn = kObjectFeatures[c.feature];
    Decision& d = R.decisions[i];
    if (is_spread(c.kind)) {
      if (R.top_added())
        d = {DecisionKind::BiasAddedFirst, "not tried: a bias form (" + name_of(top) +
                                               ") was added first, and a bias not yet in the model makes the spread "
                                               "look feature-dependent" + again};
      else
        d = {DecisionKind::OneSpreadForm, "not tried: only the best spread form is tried per run, and " +
                                              name_of(R.candidates[R.spread ? R.spread->candidate
                                                                            : R.spread_ranking.front()]) +
                                              " ranks first" +
                                              again};
    } else if (c.target != top.target && !in_manager(fn)) {
      d = {DecisionKind::NotInManager, "not added: the KPI manager cannot compute \"" + fn +
                                           "\" from a truth object, so it is added only as the top effect (without "
                                           "a model term)"};
    } else if (!R.term() || (c.target == top.target && !R.top_added())) {
      d = {DecisionKind::TopNotATerm,
           "not tried: further bias forms are tried only once the top one is a model term; the top one, " +
               name_of(top) + (R.top_added() ? ", is not: " + R.not_a_term : ", was not added")};
    } else {
      const int first = c.target == top.target ? R.top : further[c.target];
      const DecisionKind k = R.decisions[first].kind;
      d = {DecisionKind::OnePerTarget,
           "not added: at most one bias form per target is added per run, the best first: " +
               name_of(R.candidates[first]) +
               (k == DecisionKind::Added     ? " was added"
                : k == DecisionKind::MaxEffects ? " ranks first"
                                                : " was tried and not added") +
               again};
    }
  }
}

}  // namespace

void add(LoopContext& L, ObjectLoopResult& R) {
  add_top(L, R);
  add_further(L, R);
  add_spread(L, R);
  settle_untried(R);
}

}  // namespace lidarsim::qualify::obj
