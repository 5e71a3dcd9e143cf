// The object loop's last steps (object_loop.h): re-simulate the added terms through the KPI
// manager on the held-out truth objects, and refit them on every sequence.
#include <cmath>
#include <map>
#include <tuple>

#include "qualify/objects/object_loop.h"
#include "qualify/objects/object_simulated.h"
#include "qualify/report.h"

namespace fs = std::filesystem;

namespace lidarsim::qualify::obj {

namespace {

// The added spread form re-simulated: per held-out object one draw of the error with each fold's
// base and refitted model, centred on the base's conditional mean; measured errors centred the
// same way; both winsorised at the fold's fit limits. Spread error of the draws against the
// measured errors; and per fold the spread error of the fitted form itself.
void resimulate_spread(const LoopContext& L, const Candidate& sp, AddedSpread& out) {
  const int st = sp.target, sf = sp.feature;
  const FoldSet& S = L.set_of(sp);
  const std::uint64_t seed = L.options.seed;
  std::vector<double> sx, sm, sb, sa;
  for (int k = 0; k < 2; ++k) {
    const Fold& fd = S.folds[k];
    const Effect e = fit_effect(fd, st, sf, sp.kind, L.nvis, L.options.bins);
    const Losses held = held_losses(fd, e, L.nvis);
    out.fold[k] = {spread_error(held.x, held.centred, held.sd_before), spread_error(held.x, held.centred, held.sd_after)};
    const sensor::KpiModel refitted = with_spread_term(fd.base, e, kObjectFeatures[sf]);
    const auto mean = simulated_mean_error(S.motion, fd.held_idx, fd.base, kTargetParam[st], seed);
    const auto db = simulated_error_draw(S.motion, fd.held_idx, fd.base, kTargetParam[st], seed);
    const auto da = simulated_error_draw(S.motion, fd.held_idx, refitted, kTargetParam[st], seed);
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
  if (!sx.empty()) out.before_simulated = spread_error(sx, sm, sb), out.after_simulated = spread_error(sx, sm, sa);
}

// The held-out RMS of candidate c's target with what the KPI manager really uses per held-out
// truth object — the conditional mean error (noise off) or the detection probability — with each
// fold's base and with its current model (every added term); truth motion by differences, as the
// features the terms were fitted on. On the fold set c was judged on. {NaN, NaN} without objects.
std::pair<double, double> resimulated_rms(const LoopContext& L, const Candidate& c) {
  const FoldSet& S = L.set_of(c);
  const int t = c.target;
  const std::uint64_t seed = L.options.seed;
  std::vector<double> rb, ra;
  for (int k = 0; k < 2; ++k) {
    const Fold& fd = S.folds[k];
    std::map<std::array<int, 3>, double> mb, ma;
    if (t == kDetectionTarget) {
      mb = simulated_detection_probability(S.motion, fd.held_idx, fd.base, seed);
      ma = simulated_detection_probability(S.motion, fd.held_idx, S.current[k], seed);
    } else {
      mb = simulated_mean_error(S.motion, fd.held_idx, fd.base, kTargetParam[t], seed);
      ma = simulated_mean_error(S.motion, fd.held_idx, S.current[k], kTargetParam[t], seed);
    }
    for (const ObjectRecord* r : fd.held_r[t].rec) {
      const auto ib = mb.find({r->seq, r->frame, r->track}), ia = ma.find({r->seq, r->frame, r->track});
      if (ib == mb.end() || ia == ma.end()) continue;
      rb.push_back(r->value[t] - ib->second);
      ra.push_back(r->value[t] - ia->second);
    }
  }
  if (rb.empty()) return {kNaN, kNaN};
  return {rms(rb), rms(ra)};
}

// Fold 1's held-out residuals of the top one against the table fitted on its fit sequences.
std::string write_top_plot(const LoopContext& L, const ObjectLoopResult& R) {
  const Candidate& top = R.top_candidate();
  const std::string& tn = kObjectTargets[top.target];
  const std::string& fn = kObjectFeatures[top.feature];
  const std::string plot = "residual_" + tn + "_vs_" + fn + ".png";
  fs::create_directories(L.options.plots_dir);
  const Split& h = L.set_of(top).folds[0].held_r[top.target];
  const Refit& ref = R.top_judged.refs[0];
  if (ref.relative < 0) {
    write_residual_png(L.options.plots_dir / plot, ref.table.pooled, h.column(top.feature), h.r,
                       {"Held-out " + tn + " residual vs " + fn + " (fold 1)", feature_axis_label(fn),
                        tn + " residual, measured - model " + target_unit(tn)});
    return plot;
  }
  // A relative term's table is a share of the object's size: the residual is drawn as one too.
  const std::string& sn = kObjectFeatures[ref.relative];
  std::vector<double> share = h.r;
  const auto s = relative_values(h, ref);
  for (size_t i = 0; i < share.size(); ++i) share[i] = s[i] > 0 ? share[i] / s[i] : 0.0;
  write_residual_png(L.options.plots_dir / plot, ref.table.pooled, h.column(top.feature), share,
                     {"Held-out " + tn + " residual / " + sn + " vs " + fn + " (fold 1)", feature_axis_label(fn),
                      tn + " residual / the object's " + sn + " (share)"});
  return plot;
}

}  // namespace

void resimulate(LoopContext& L, ObjectLoopResult& R) {
  if (R.spread) resimulate_spread(L, R.candidates[R.spread->candidate], *R.spread);
  std::tie(R.top_before_simulated, R.top_after_simulated) = resimulated_rms(L, R.top_candidate());
  for (AddedBias& a : R.added)
    std::tie(a.before_simulated, a.after_simulated) =
        a.candidate == R.top ? std::make_pair(R.top_before_simulated, R.top_after_simulated)
                             : resimulated_rms(L, R.candidates[a.candidate]);
}

// The model to use from now on: base and terms fitted on every sequence (each error term with the
// noise shrunk for it, for the classes that kept it); the false positives judged apart, on their
// own outcome and stream; the model written where asked.
void refit(LoopContext& L, ObjectLoopResult& R) {
  const LoopOptions& o = L.options;
  const Candidate& top = R.top_candidate();
  Fold whole;
  whole.pool_track_spread = o.pool_track_spread;
  std::vector<int> all(L.data.calib.size());
  for (size_t s = 0; s < all.size(); ++s) all[s] = static_cast<int>(s);
  make_fold(whole, L.data, all, {}, L.fit);
  whole.shrink_terms = o.shrink_terms;
  R.track_spread_factor = whole.track_spread_factor;
  R.top_whole = fit_effect(whole, top.target, top.feature, top.kind, L.nvis, o.bins).bias;
  if (R.spread) {
    const Candidate& sp = R.candidates[R.spread->candidate];
    R.spread->whole = fit_effect(whole, sp.target, sp.feature, sp.kind, L.nvis, o.bins);
  }
  sensor::KpiModel model = whole.base;
  if (R.term())
    for (const AddedBias& a : R.added) {
      const Candidate& c = R.candidates[a.candidate];
      const int t = c.target;
      const Refit r = a.candidate == R.top ? R.top_whole : fit_effect(whole, t, c.feature, c.kind, L.nvis, o.bins).bias;
      model = t == kDetectionTarget ? with_term(model, r, t, kObjectFeatures[c.feature], L.nvis)
                                    : with_term_and_noise(model, r, t, kObjectFeatures[c.feature], L.nvis,
                                                          whole.fit_r[t], whole.win[t], a.judged.classes);
    }
  else if (R.spread)
    model = with_spread_term(whole.base, R.spread->whole, kObjectFeatures[R.candidates[R.spread->candidate].feature]);
  R.false_positives = analyse_false_positives(L.data, L.sets[0]->folds, o.threshold, o.bins, o.seed);
  if (!o.out_model.empty()) {
    const FpAnalysis& fpa = R.false_positives;
    if (fpa.added >= 0) model = with_fitted_fp_table(model, whole, fpa.candidates[fpa.added], o.bins);
    if (fpa.persistence.added) model = with_fp_persistence(model, L.data, whole.fit_idx, whole.fit_set, o.seed);
    sensor::save_kpi_model(model, o.out_model);
  }
  const FoldSet& S = L.set_of(top);
  R.top_scheme = S.scheme;
  for (int k = 0; k < 2; ++k)
    R.fit_names[k] = names_of(*S.data, S.folds[k].fit_idx), R.held_names[k] = names_of(*S.data, S.folds[k].held_idx);
  if (!o.plots_dir.empty()) R.plot = write_top_plot(L, R);
}

}  // namespace lidarsim::qualify::obj
