// The intensity loop: one round is four named steps that fill a typed result (RoundResult):
//   fit the base      per fold, on the fold's training cells; pooled over the folds' held-out cells
//   rank              every feature x form on the pooled held-out residual (intensity_forms.cpp)
//   refit             the top feature as the base model would carry it, per fold, judged held out
//   decide            add it or not, and record why for every candidate
// The JSON is written from the result (intensity_report.cpp).
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "common/error.h"
#include "data/baselines.h"
#include "nn/checkpoint.h"
#include "nn/receptive_field.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/report.h"
#include "qualify/windows.h"

namespace fs = std::filesystem;

namespace lidarsim::qualify {

namespace {

using namespace intensity_detail;

std::string pct(double share) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f %%", 100 * share);
  return b;
}
std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

int default_folds(const IntensityLoopOptions& o) {
  if (o.folds > 0) return o.folds;
  // Rotating folds need a guarded region split; the UNet base trains every model once per fold.
  const bool regions = o.split.rfind("guarded", 0) == 0;
  return regions && o.base_model != Base::Unet ? 4 : 1;
}

void check_loop_options(const IntensityLoopOptions& o) {
  const Base base = o.base_model;
  if (o.unet.seeds < 1 || o.unet.steps < 1 || o.unet.threads < 1)
    throw Error("loop intensity: --seeds, --steps and --threads must be at least 1");
  if (o.unet.lookup_base && base != Base::Unet)
    throw Error("loop intensity: --lookup-base: only with --base unet (the UNets learn the residual over the lookup)");
  if (o.rounds < 1 || o.rounds > 9) throw Error("loop intensity: --rounds: expected 1..9, got " + std::to_string(o.rounds));
  if (!(o.min_relative_gain >= 0 && o.min_relative_gain < 1))
    throw Error("loop intensity: --min-gain: expected a share in [0, 1), got " + std::to_string(o.min_relative_gain));
  if (o.folds != 0 && o.folds != 1 && o.folds != 4)
    throw Error("loop intensity: --folds: expected 1 or 4, got " + std::to_string(o.folds));
}

// What every round shares: the folds and their pooled held-out cells.
struct Context {
  const data::Dataset& ds;
  const IntensityLoopOptions& o;
  Base base;
  data::SectorSplit split;
  int half_width = 0;
  std::vector<Fold> folds;
  Pooled pool;
  TrainingCount count;
};

struct BaseFit {
  std::vector<UnetFits> unet;  // per fold (UNet base)
};

std::vector<double> pooled_seed_mae(const Context& cx, const std::vector<UnetFits>& fits) {
  std::vector<double> out;
  for (int s = 0; s < cx.o.unet.seeds; ++s) {
    std::vector<std::vector<double>> per_fold;
    for (const auto& f : fits) per_fold.push_back(f.seed_pred[s]);
    out.push_back(errors(pool_prediction(cx.folds, per_fold), cx.pool.measured).mae);
  }
  return out;
}

// Step 1: the base model per fold; cx.pool.base = its held-out prediction.
BaseFit fit_base(Context& cx, const std::vector<double>* prior) {
  BaseFit b;
  std::vector<std::vector<double>> per_fold;
  for (size_t k = 0; k < cx.folds.size(); ++k) {
    const Fold& f = cx.folds[k];
    if (cx.base == Base::Unet) {
      b.unet.push_back(fit_unets(f.ds, f.cells, kIntensityFeaturesUsedByModel, cx.o,
                                 "base, fold " + std::to_string(k + 1) + "/" + std::to_string(cx.folds.size()),
                                 cx.count));
      per_fold.push_back(b.unet.back().ensemble);
    } else if (cx.base == Base::LookupBeam) {
      per_fold.push_back(lookup_beam_prediction(f.cells, cx.ds.rows()));
    }
  }
  cx.pool.base = prior ? *prior : cx.base == Base::Lookup ? cx.pool.lookup : pool_prediction(cx.folds, per_fold);
  return b;
}

// The folds for the joint refit of a lookup (its first round: a refitted lookup would drop the
// effects added before), else none.
const std::vector<Fold>* joint_folds(const Context& cx, const std::vector<std::string>& added_before) {
  return cx.base == Base::Lookup && added_before.empty() ? &cx.folds : nullptr;
}

// Why a feature x form is not ranked: the base model already carries it.
std::string used_reason(Base base, const std::string& feature, Form form, const std::vector<std::string>& added_before) {
  const auto& u = kIntensityFeaturesUsedByModel;
  if (std::find(u.begin(), u.end(), feature) != u.end())
    return "not ranked: the base model already uses " + feature + " as an input";
  if (std::find(added_before.begin(), added_before.end(), feature) != added_before.end())
    return "not ranked: " + feature + " was added in an earlier round";
  if (base == Base::LookupBeam && feature == "beam_row" && additive(form))
    return "not ranked: the lookup-beam base already has an offset per beam row";
  return "";
}

// A feature's bins: the tables' (cx.o.bins equal-count bins, or one per beam row) and the windows'
// fine bins (32). Equal-count edges depend only on the values, so both are found on one sorted
// copy (sorting and binning sorted values is the cheap case).
std::pair<std::vector<double>, std::vector<double>> feature_bins(const std::vector<double>& x, bool per_row,
                                                                 const Context& cx) {
  if (per_row) return {category_edges(cx.ds.rows()), category_edges(cx.ds.rows())};
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  return {equal_count_edges(sorted, cx.o.bins), equal_count_edges(sorted, 32)};
}

// Step 2: every feature in every form, scored on the pooled held-out residual; best first.
void rank(RoundResult& r, const Context& cx, const std::vector<double>& rc, const std::vector<std::string>& added_before) {
  // A lookup base's refit scores each form of the top feature again, keeping every cell's
  // prediction: the same computation as here. So the predictions of the best feature so far
  // (the best rankable form's R^2; the first of equals, as the stable sort below) are kept.
  const bool keep = cx.base != Base::Unet;
  const std::vector<Fold>* folds = joint_folds(cx, added_before);
  std::string best_feature;
  double best_r2 = 0;
  for (size_t f = 0; f < kIntensityFeatures.size(); ++f) {
    const size_t first = r.candidates.size();
    const std::string& name = kIntensityFeatures[f];
    const bool per_row = name == "beam_row";
    const auto& x = cx.pool.feature[f];
    const auto [edges, fine] = feature_bins(x, per_row, cx);
    for (Form form : kForms) {
      if (form == Form::RangeSlope && !range_interaction_applies(name)) continue;
      Candidate k;
      k.feature = name, k.form = form, k.per_row = per_row;
      k.score = score_form(form, cx.pool, f, edges, fine, rc, keep, folds);
      if (!k.score.shown.ok()) continue;  // a window needs 3 fine bins (depth_discontinuity has 2)
      if (keep) {
        k.refit_corrected = std::move(k.score.corrected), k.refit_mae = k.score.mae_after;
        k.kept = true, k.refit_folds = folds;
        k.score.corrected = {};
      }
      k.reason = used_reason(cx.base, name, form, added_before);
      if (k.reason.empty()) check_across_scenery(k, cx.pool, f, edges, fine, rc);
      k.used = !k.reason.empty();
      if (k.used) k.decision = Decision::NotRanked;
      if (!k.used && name == "azimuth" && !cx.pool.azimuth_undecided.empty()) {
        k.undecided = true, k.decision = Decision::CannotDecide;
        k.reason = "the data cannot decide: " + cx.pool.azimuth_undecided;
      } else if (!k.used && cross_fit_for(cx.pool, name).crossed &&
                 !(joint_folds(cx, added_before) && joint_azimuth_gain(cx.pool, name, form))) {
        k.undecided = true, k.decision = Decision::CannotDecide;
        k.reason = std::string("the data cannot decide: on scans of one scenery azimuth is judged across classes x row "
                               "blocks as a gain with the lookup refitted jointly (") +
                   (joint_folds(cx, added_before) ? "an additive or affine form fitted on other classes carries the "
                                                    "plain lookup's bias of theirs, which differs per class"
                                                  : "a lookup base's first round only") +
                   ")";
      }
      if (form == Form::Table) r.residual_tables[name] = k.score.shown.table;
      r.candidates.push_back(std::move(k));
    }
    if (!keep) continue;
    bool rankable = false;
    double r2 = 0;
    for (size_t q = first; q < r.candidates.size(); ++q) {
      const Candidate& k = r.candidates[q];
      if (!k.used && !k.undecided && (!rankable || k.score.r2 > r2)) r2 = k.score.r2, rankable = true;
    }
    if (rankable && (best_feature.empty() || r2 > best_r2)) best_feature = name, best_r2 = r2;
    for (Candidate& k : r.candidates)
      if (k.kept && k.feature != best_feature) k.refit_corrected = {}, k.kept = false;
  }
  std::stable_sort(r.candidates.begin(), r.candidates.end(),
                   [](const Candidate& a, const Candidate& b) { return a.score.r2 > b.score.r2; });
  // Best form per feature (the candidates are sorted: the first seen is the best).
  for (const Candidate& k : r.candidates) {
    auto& list = k.used ? r.used : k.undecided ? r.undecided : r.ranking;
    const bool seen = std::any_of(list.begin(), list.end(), [&](const FeatureScore& s) { return s.feature == k.feature; });
    if (seen) continue;
    list.push_back({k.feature, k.score.r2, "intensity", k.score.interval});
    if (&list == &r.ranking) r.ranking_form.push_back(k.name()), r.ranking_mae.push_back(k.score.mae_after);
  }
  if (r.ranking.empty())
    throw Error("loop intensity: every feature is used by the base model or undecided: nothing to rank");
  r.top_feature = r.ranking.front().feature;
  r.top_form = r.ranking_form.front();
  r.candidate = r.ranking.front().score >= cx.o.threshold;
  // A feature the data cannot decide on that explains more than the top one: the top one may only
  // stand in for it (a window of azimuth shows up in the heights of the scenery in it), so adding
  // it would be a guess. Nothing is tried, and the report says why.
  // (Azimuth on one scenery has ranked gain forms and undecided others; a dark object of one
  // class shows up in its affine form and in height alike, so the rule holds unless azimuth is
  // itself the top feature.)
  if (r.candidate && !r.undecided.empty() && r.undecided.front().feature != r.top_feature &&
      r.undecided.front().score > r.ranking.front().score) {
    r.candidate = false;
    r.not_tried_why = r.undecided.front().feature + " explains more of the held-out residual (R^2 " +
                      num(r.undecided.front().score) + " vs " + num(r.ranking.front().score) +
                      ") and the data cannot decide on it; " + r.top_feature + " may only stand in for it";
  }
}

std::string refit_kind(Form f) {
  if (f == Form::RangeSlope) return "gain a power of range per bin";
  return additive(f) ? "additive correction" : f == Form::AffineTable ? "gain and offset" : "gain";
}

// Step 3 for the UNet: the top feature as the network would carry it, retrained per fold with the
// same seeds: beam_row as a learned gain and offset per PGM row on the output (nn/unet.h,
// row_affine; the row is known wherever a PGM is), any other feature as a new input channel.
std::vector<double> refit_unet(RoundResult& r, Context& cx, std::vector<UnetFits>& after_fits) {
  const bool row = r.top_feature == "beam_row";
  std::vector<std::string> channels = kIntensityFeaturesUsedByModel;
  std::string added;
  if (!row)
    for (const auto& ch : channels_of(r.top_feature)) channels.push_back(ch), added += (added.empty() ? "" : ", ") + ch;
  std::vector<std::vector<double>> per_fold;
  for (size_t k = 0; k < cx.folds.size(); ++k) {
    const Fold& f = cx.folds[k];
    const std::string label = (row ? "with a per-row affine layer" : "with " + added) + ", fold " +
                              std::to_string(k + 1) + "/" + std::to_string(cx.folds.size());
    after_fits.push_back(row ? fit_unets(f.ds, f.cells, channels, cx.o, label, cx.count, true)
                             : fit_unets(with_derived_channels(f.ds, channels), f.cells, channels, cx.o, label, cx.count));
    per_fold.push_back(after_fits.back().ensemble);
  }
  const std::vector<double> after = pool_prediction(cx.folds, per_fold);
  r.method = row ? "learned per-row affine layer (gain and offset per beam row on the output), UNet retrained"
                 : "new PGM input channel \"" + r.top_feature + "\" (" + added + "), UNet retrained";
  r.refits.push_back({r.method, errors(after, cx.pool.measured).mae, true});
  if (row)
    // A gain table on the base UNets' prediction corrects under-training as well as a sensor
    // effect (the control set's short-trained UNet "improves" with it too): reported, not added.
    for (const Candidate& k : r.candidates)
      if (k.feature == "beam_row" && k.form == Form::GainTable)
        r.refits.push_back({"per-beam gain table on the UNet's prediction (measured, not addable)", k.score.mae_after, false});
  r.seeds_tried = pooled_seed_mae(cx, after_fits);
  return after;
}

// Step 3 for a lookup base: every form of the top feature applied as fitted (cross-fitted over
// the pool's groups), and the lookup refitted with the feature's bin as an extra key (first
// round only: a refitted lookup would drop the effects added before). The lowest held-out MAE wins.
std::vector<double> refit_lookup(RoundResult& r, const Context& cx, const std::vector<double>& rc, bool has_prior) {
  const size_t tf = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), r.top_feature) -
                    kIntensityFeatures.begin();
  const auto& x = cx.pool.feature[tf];
  const bool per_row = r.top_feature == "beam_row";
  const auto [edges, fine] = feature_bins(x, per_row, cx);
  std::vector<double> best = cx.pool.base;
  double best_mae = errors(cx.pool.base, cx.pool.measured).mae;
  for (Candidate& k : r.candidates) {
    if (k.feature != r.top_feature || k.used) continue;
    const std::vector<Fold>* folds = cx.base == Base::Lookup && !has_prior ? &cx.folds : nullptr;
    FormScore s;
    if (k.kept && k.refit_folds == folds) {
      s.corrected = std::move(k.refit_corrected), s.mae_after = k.refit_mae;
      k.kept = false;
    } else {
      s = score_form(k.form, cx.pool, tf, edges, fine, rc, true, folds);
    }
    const bool joint = folds && joint_azimuth_gain(cx.pool, k.feature, k.form);
    const std::string name = k.name() + ": " + (joint ? "gain, the lookup refitted jointly with it" : refit_kind(k.form));
    r.refits.push_back({name, s.mae_after, true});
    if (s.mae_after < best_mae) best_mae = s.mae_after, best = s.corrected, r.method = name;
  }
  // The lookup keyed by the bin is fitted on each fold's fit columns: for azimuth cross-fitted over
  // classes x row blocks (one scenery), it would carry the scenery of the neighbouring columns.
  const bool scenery = cross_fit_for(cx.pool, r.top_feature).crossed;
  if (cx.base == Base::Lookup && !has_prior && !scenery) {
    const BinnedTable bins{edges, std::vector<double>(edges.size() + 1, 0.0), {}};
    std::vector<std::vector<double>> per_fold;
    for (const Fold& f : cx.folds) {
      const IntensityCells& c = f.cells;
      per_fold.push_back(lookup(
          c, [&](size_t i) { return (long(c.cls[i]) * 1000 + data::range_bin(c.feature[0][i])) * 1000 + bins.bin(c.feature[tf][i]); },
          lookup_prediction(c)));
    }
    const std::vector<double> pr = pool_prediction(cx.folds, per_fold);
    const std::string name = form_name(Form::Table, per_row) + ": lookup refitted with the bin as a key";
    const double mae = errors(pr, cx.pool.measured).mae;
    r.refits.push_back({name, mae, true});
    if (mae < best_mae) best_mae = mae, best = pr, r.method = name;
  }
  if (cx.base == Base::Lookup && !has_prior && range_interaction_applies(r.top_feature)) {
    std::vector<std::vector<double>> per_fold;
    for (const Fold& f : cx.folds) per_fold.push_back(lookup_with_range_slope(f.cells, tf, edges));
    const std::vector<double> pr = pool_prediction(cx.folds, per_fold);
    const std::string name = form_name(Form::RangeSlope, per_row) + ": lookup refitted jointly with the slope";
    const double mae = errors(pr, cx.pool.measured).mae;
    r.refits.push_back({name, mae, true});
    if (mae < best_mae) best_mae = mae, best = pr, r.method = name;
  }
  return best;
}

// Step 4: add or not, and every candidate's decision in words a user acts on.
void decide(RoundResult& r, const Context& cx, const std::vector<double>& after) {
  r.tried = errors(after, cx.pool.measured);
  r.interval = change_interval(cx.pool, after);
  const double cut = r.before.mae > 0 ? 1 - r.tried.mae / r.before.mae : 0;
  const std::string interval = "95 % interval of the change [" + num(r.interval[0]) + ", " + num(r.interval[1]) + "]";
  r.added = r.candidate && r.interval[1] < 0 && r.tried.mae <= (1 - cx.o.min_relative_gain) * r.before.mae;
  std::string verdict;
  if (!r.candidate)
    verdict = !r.not_tried_why.empty() ? "not tried: " + r.not_tried_why
                                       : "not tried: its held-out R^2 " + num(r.ranking.front().score) +
                                             " is below the threshold " + num(cx.o.threshold);
  else if (r.added)
    verdict = "added: the refit cut the held-out MAE by " + pct(cut) + " (" + num(r.before.mae) + " -> " +
              num(r.tried.mae) + "), " + interval;
  else if (r.method == "none")
    verdict = "not added: no refit lowered the held-out MAE below " + num(r.before.mae);
  else if (r.interval[1] >= 0)
    verdict = "not added: the refit did not lower the held-out error beyond the block-bootstrap noise (" + interval + ")";
  else
    verdict = "not added: the refit cut the held-out MAE by " + pct(cut) + " < min gain " + pct(cx.o.min_relative_gain);
  if (r.candidate && !r.added) r.rejected_why = verdict.substr(verdict.find(": ") + 2);
  const std::string chosen_form = r.method.substr(0, r.method.find(": "));
  for (Candidate& k : r.candidates) {
    if (k.used || k.undecided) continue;
    const bool top = k.feature == r.top_feature;
    bool chosen = false;  // the form whose refit the verdict is about
    if (top) chosen = k.name() == (cx.base == Base::Unet || r.method == "none" ? r.top_form : chosen_form);
    if (!top) {
      k.decision = Decision::NotTried;
      k.reason = "not tried: " + r.top_feature + " ranks first (held-out R^2 " + num(r.ranking.front().score) +
                 " vs " + num(k.score.r2) + "); one effect is tried per round";
    } else if (chosen || !r.candidate) {
      k.decision = !r.candidate ? Decision::NotTried : r.added ? Decision::Added : Decision::NotAdded;
      k.reason = verdict;
    } else if (cx.base == Base::Unet) {
      k.decision = Decision::NotTried;
      k.reason = "not tried: the " + r.top_form + " form ranks higher; the UNet's refit (" + r.method + ") is one per feature";
    } else {
      k.decision = Decision::Tried;
      k.reason = "tried: held-out MAE " + num(k.score.mae_after) + " with it; the refit \"" + r.method +
                 "\" is lower (" + num(r.tried.mae) + ")";
    }
    if (k.scenery_checked && k.column_r2 > k.score.r2)
      k.reason += "; held-out R^2 " + num(k.column_r2) + " cross-fitted over columns, " + num(k.score.r2) +
                  " across classes x row blocks in the same columns (the lower counts: on scans of one scenery " +
                  k.feature + " may stand in for an effect of azimuth)";
  }
}

// One round of the loop. Later rounds of a lookup loop start from the previous round's prediction
// (`prior`, pooled held-out cells) with the features added before set aside.
RoundResult loop_round(Context& cx, const std::vector<std::string>& added_before, const std::vector<double>* prior,
                       std::vector<double>& after) {
  RoundResult r;
  r.split = cx.split.describe(cx.ds.cols()) +
            (cx.folds.size() > 1 ? "; the regions rotated over " + std::to_string(cx.folds.size()) +
                                       " folds by their width each, so every column is validated once"
                                 : std::string());
  r.folds = static_cast<int>(cx.folds.size());
  r.group_by = cx.pool.group_by;
  r.azimuth_group_by = cx.pool.azimuth_scenery.by;
  r.scenery_correlation = cx.pool.scenery_correlation;
  r.time_block_correlation = cx.pool.time_block_correlation;
  r.half_width = cx.half_width;
  BaseFit base = fit_base(cx, prior);
  if (cx.base == Base::Unet) r.seeds_before = pooled_seed_mae(cx, base.unet);
  r.before = errors(cx.pool.base, cx.pool.measured);
  r.lookup_before = errors(cx.pool.lookup, cx.pool.measured).mae;

  std::vector<double> resid(cx.pool.size()), rc(cx.pool.size());
  for (size_t i = 0; i < rc.size(); ++i) resid[i] = cx.pool.measured[i] - cx.pool.base[i];
  const Winsor w = winsor_limits(resid);
  for (size_t i = 0; i < rc.size(); ++i) rc[i] = w(resid[i]);

  rank(r, cx, rc, added_before);
  std::vector<UnetFits> after_fits;
  after = cx.pool.base;
  if (r.candidate) after = cx.base == Base::Unet ? refit_unet(r, cx, after_fits) : refit_lookup(r, cx, rc, prior != nullptr);
  decide(r, cx, after);
  if (!r.added) after = cx.pool.base;
  r.after = errors(after, cx.pool.measured);
  if (cx.base == Base::Unet) r.seeds_after = r.added ? r.seeds_tried : r.seeds_before;
  // The form the refit used (a lookup's), else the top feature's best form.
  for (const Candidate& k : r.candidates)
    if (k.feature == r.top_feature && !k.used && (r.method.rfind(k.name() + ":", 0) == 0 || !r.effect_table.ok()))
      r.effect_table = k.score.shown;

  if (r.added && !cx.o.plots_dir.empty()) {
    const size_t tf = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), r.top_feature) -
                      kIntensityFeatures.begin();
    fs::create_directories(cx.o.plots_dir);
    r.plot = "residual_intensity_vs_" + r.top_feature + ".png";
    write_residual_png(cx.o.plots_dir / r.plot, r.residual_tables.at(r.top_feature), cx.pool.feature[tf], resid,
                       {"Held-out intensity residual vs " + r.top_feature, feature_axis_label(r.top_feature),
                        "intensity residual, measured - " + to_string(cx.o.base_model) + " (0..1 scale)"});
  }
  if (cx.base == Base::Unet && !cx.o.out_model.empty()) {
    // Weights only, as lidar-train --export-weights writes them: lidar-infer loads it as is. The
    // first fold's (the guarded split as it is), first seed's.
    const train::TrainResult& m = (r.added ? after_fits : base.unet).front().first;
    nn::save_checkpoint(cx.o.out_model, *m.model, nullptr, m.meta);
  }
  return r;
}

}  // namespace

nlohmann::json loop_intensity(const fs::path& dir, const IntensityLoopOptions& options) {
  check_loop_options(options);  // before the import: a typo should not wait for it
  return loop_intensity(import_for_qualify(dir), options);
}

nlohmann::json loop_intensity(const data::Dataset& ds, const IntensityLoopOptions& options) {
  check_loop_options(options);
  const data::SectorSplit split = intensity_split(ds, options.split, options.unet.depth);
  std::vector<Fold> folds = make_folds(ds, split, default_folds(options));
  Pooled pooled = pool(folds, ds.cols(), scenery_correlation(ds), time_blocks(ds));
  const int trainings = 2 * options.unet.seeds * static_cast<int>(folds.size());
  Context cx{ds,
             options,
             options.base_model,
             split,
             nn::receptive_field_half_width({1, 1, options.unet.base, options.unet.depth}),
             std::move(folds),
             std::move(pooled),
             {0, trainings}};
  if (cx.base != Base::Lookup && cx.pool.azimuth_scenery.groups > 0) {
    // Judged across classes x row blocks only as a gain with the lookup's levels refitted jointly.
    cx.pool.azimuth_scenery = {};
    cx.pool.azimuth_undecided = cx.pool.azimuth_columns +
                                "; across classes x row blocks in the same columns only with --base lookup (its levels "
                                "are refitted jointly with the gain)";
  }
  std::vector<double> after;
  const RoundResult first = loop_round(cx, {}, nullptr, after);
  nlohmann::json j = to_json(first, options);
  if (options.rounds <= 1 || cx.base == Base::Unet) return j;
  // Further rounds on a lookup: the next effect against the prediction with the ones added so far.
  std::vector<std::string> added;
  nlohmann::json rounds = nlohmann::json::array({round_summary(j)});
  for (RoundResult r = first; r.added && static_cast<int>(rounds.size()) < options.rounds;) {
    added.push_back(r.top_feature);
    const std::vector<double> prior = after;
    r = loop_round(cx, added, &prior, after);
    rounds.push_back(round_summary(to_json(r, options)));
  }
  j["rounds"] = rounds;
  j["after_all_rounds"] = rounds.back()["after"];
  return j;
}

}  // namespace lidarsim::qualify
