// The object loop's false-positive candidates judged on the cross-fit (object_false_positives.h).
#include "qualify/objects/object_false_positives.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

#include "common/angles.h"
#include "common/plot.h"
#include "qualify/objects/object_fp_cell.h"
#include "qualify/report.h"
#include "sensor/kpi_fit.h"

namespace lidarsim::qualify::obj {

namespace {

// One fold's false-positive data: grid, fit and held-out counts, the base model.
struct Side {
  FpGrid g;
  FpData fit, held;
  PerClass<double> floor{};
  FpModel base;
  std::array<std::vector<double>, kObjectClassCount + 1> dev_base;  // per judged class (all, Car, Pedestrian, Cyclist), per block
};

bool judged(int c, int cls) { return cls < 0 || c == cls; }

// Poisson deviance of each block's held-out counts per class and cell against the model's expected
// counts summed over the block's frames (indexed by block; 0 for blocks of the other fold); of class
// `cls`'s cells only, or every class's (-1).
std::vector<double> block_deviance(const FpModel& m, const FpData& held, size_t nblocks, int cells, int cls) {
  std::vector<std::vector<double>> Y(nblocks), M(nblocks);
  for (const auto& fr : held.frames) {
    auto &y = Y[fr.block], &mu = M[fr.block];
    if (y.empty()) y.assign(kObjectClassCount * cells, 0.0), mu.assign(kObjectClassCount * cells, 0.0);
    const int b = m.frame_bin(fr);
    for (int c = 0; c < kObjectClassCount; ++c) {
      const auto& cm = m.mu[c][std::min<size_t>(b, m.mu[c].size() - 1)];
      for (int k = 0; k < cells; ++k) mu[c * cells + k] += cm[k];
    }
    for (const auto& [c, cell, n] : fr.counts) y[c * cells + cell] += n;
  }
  std::vector<double> d(nblocks, 0.0);
  for (size_t b = 0; b < nblocks; ++b)
    for (size_t k = 0; k < Y[b].size(); ++k)
      if (judged(static_cast<int>(k) / cells, cls))
        d[b] += 2 * ((Y[b][k] > 0 ? Y[b][k] * std::log(Y[b][k] / M[b][k]) : 0.0) - (Y[b][k] - M[b][k]));
  return d;
}

// Per class and cell: (held-out false positives per frame, the model's mean expected count); of class
// `cls` only, or of every class (-1).
std::vector<std::array<double, 3>> rate_pairs(const FpModel& m, const FpData& held, int cells, int cls = -1) {
  std::vector<std::array<double, 3>> p(kObjectClassCount * cells, {0, 0, 0});
  for (const auto& fr : held.frames) {
    const int b = m.frame_bin(fr);
    for (int c = 0; c < kObjectClassCount; ++c) {
      const auto& mu = m.mu[c][std::min<size_t>(b, m.mu[c].size() - 1)];
      for (int k = 0; k < cells; ++k) p[c * cells + k][1] += mu[k];
    }
    for (const auto& [c, cell, y] : fr.counts) p[c * cells + cell][0] += y;
  }
  const double n = std::max<size_t>(1, held.frames.size());
  for (auto& e : p) e[0] /= n, e[1] /= n, e[2] = e[0] / n;  // Poisson variance of the measured rate
  if (cls >= 0) p = std::vector<std::array<double, 3>>(p.begin() + cls * cells, p.begin() + (cls + 1) * cells);
  return p;
}

std::string form_of(const FpModel& m, bool window) {
  std::ostringstream o;
  if (m.cell_rate >= 0) {
    o << "cell, range " << fmt(m.cell[0], 3) << "-" << fmt(m.cell[1], 3) << " m x azimuth " << fmt(m.cell[2] / kDeg, 3)
      << "-" << fmt(m.cell[3] / kDeg, 3) << " deg; the cell's rate per frame " << fmt(m.cell_rate, 3);
    return o.str();
  }
  if (!window) {
    o << "table, " << m.cuts.size() + 1 << " bins";
    return o.str();
  }
  if (m.cuts.empty()) return "no window found";
  o << (m.cuts.size() == 2 ? "window, edges" : "step, edge");
  for (double v : m.cuts) o << " " << fmt(v, 3);
  o << "; rate per frame (all classes)";
  for (size_t b = 0; b < m.cuts.size() + 1; ++b) {
    double r = 0;
    for (int c = 0; c < kObjectClassCount; ++c) r += b < m.comps[c].size() ? m.comps[c][b].rate : 0;
    o << " " << fmt(r, 3);
  }
  return o.str();
}

double change_per_frame(const std::array<double, 3>& s) { return s[2] > 0 ? (s[0] - s[1]) / s[2] : 0.0; }

// The simulated false positives per frame and cell on fold k's held-out sequences, 4 seeds.
std::vector<std::array<double, 3>> simulated_pairs(const TrackingData& data, const Fold& fold, const Side& side,
                                                   const sensor::KpiModel& model, std::uint64_t seed) {
  const int cells = side.g.cells();
  std::vector<std::array<double, 3>> p(kObjectClassCount * cells, {0, 0, 0});
  FpModel measured = fp_base(fold.base);  // only for the measured side of the pairs
  measured.compile(side.g, side.floor);
  const auto meas = rate_pairs(measured, side.held, cells);
  const int seeds = 4;
  for (int s = 0; s < seeds; ++s) {
    const auto sim = sensor::resimulate(data.calib, model, seed + 200 + s);
    const ObjectSet set = collect_objects(data, fold.held_idx, &sim);
    for (const auto& r : set.fp_records)
      p[r.cls * cells + side.g.cell(r.range, r.azimuth, r.score)][1] += 1.0 / seeds;
  }
  const double n = std::max<size_t>(1, side.held.frames.size());
  for (size_t i = 0; i < p.size(); ++i) p[i] = {meas[i][0], p[i][1] / n, meas[i][2] + p[i][1] / n / (seeds * n)};
  return p;
}

// The held-out blocks of both folds: how many, their frames, which fold holds each out.
struct Blocks {
  size_t n = 0;
  std::vector<double> frames;
  std::vector<int> fold;
};

// One candidate (feature, form, class) fitted on each fold's fit split (`fitted`) and judged on the
// held-out blocks: on every class's cells, or on class `cls`'s only.
FpCandidate judge_candidate(const std::array<Side, 2>& side, const std::array<Fold, 2>& folds, const Blocks& blocks,
                            int f, bool window, bool cell, int cls, int bins, std::array<FpModel, 2>& fitted) {
  FpCandidate c;
  c.feature = f, c.window = window, c.cell = cell, c.cls = cls;
  BlockSums sums(blocks.n, {0, 0, 0});
  std::array<double, 3> total{0, 0, 0};
  std::array<std::vector<std::array<double, 3>>, 2> before, after;
  for (int k = 0; k < 2; ++k) {
    const Side& s = side[k];
    fitted[k] = cell ? fit_fp_cell(s.fit, folds[k].base, bins, s.g, s.floor, cls)
                     : fit_fp_model(s.fit, folds[k].base, f, window, bins, s.g, s.floor, cls);
    const auto dev = block_deviance(fitted[k], s.held, blocks.n, s.g.cells(), cls);
    const auto& dev0 = s.dev_base[cls + 1];
    for (size_t b = 0; b < blocks.n; ++b) {
      if (blocks.fold[b] != k) continue;
      sums[b][0] += dev[b], sums[b][1] += dev0[b], sums[b][2] += blocks.frames[b];
      total[0] += dev[b], total[1] += dev0[b], total[2] += blocks.frames[b];
    }
    before[k] = rate_pairs(s.base, s.held, s.g.cells(), cls);
    after[k] = rate_pairs(fitted[k], s.held, s.g.cells(), cls);
  }
  c.form = form_of(fitted[0], window);
  double moved = 0, mass = 0;
  for (size_t i = 0; i < before[0].size(); ++i)
    moved += std::abs(after[0][i][1] - before[0][i][1]), mass += before[0][i][1];
  c.effect_size = mass > 0 ? 0.5 * moved / mass : 0;
  BlockSums used;
  for (const auto& b : sums)
    if (b[2] > 0) used.push_back(b);
  c.score = r2_of_sums(total);
  c.interval = block_bootstrap_interval(used, r2_of_sums);
  c.change = block_bootstrap_interval(used, change_per_frame);
  c.deviance_before = total[2] > 0 ? total[1] / total[2] : 0;
  c.deviance_after = total[2] > 0 ? total[0] / total[2] : 0;
  c.error_before = fp_rate_error(before);
  c.error_after = fp_rate_error(after);
  c.frames = static_cast<long>(total[2]);
  return c;
}

}  // namespace

double fp_rate_error(const std::array<std::vector<std::array<double, 3>>, 2>& per_fold) {
  double s = 0;
  long n = 0;
  for (const auto& v : per_fold)
    for (const auto& [a, b, var] : v) s += (a - b) * (a - b) - var, ++n;
  return n ? std::sqrt(std::max(0.0, s / n)) : 0;
}

FpAnalysis analyse_false_positives(const TrackingData& data, const std::array<Fold, 2>& folds, double threshold,
                                   int bins, std::uint64_t seed) {
  FpAnalysis A;
  std::array<Side, 2> side;
  std::map<int, int> block_id;
  for (int k = 0; k < 2; ++k) {
    Side& s = side[k];
    s.g = fp_grid(folds[k].fit_set);
    s.fit = fp_data(folds[k].fit_set, s.g);
    s.held = fp_data(folds[k].held_set, s.g);
    s.floor = fp_floor(s.fit, s.g.cells());
    s.base = fp_base(folds[k].base, s.fit);
    s.base.compile(s.g, s.floor);
    for (auto& fr : s.held.frames) fr.block = block_id.try_emplace(fr.block, static_cast<int>(block_id.size())).first->second;
    A.frames += static_cast<int>(s.held.frames.size());
    A.fps += static_cast<int>(s.held.fps.size());
  }
  Blocks blocks;
  blocks.n = block_id.size();
  blocks.frames.assign(blocks.n, 0.0);
  blocks.fold.assign(blocks.n, 0);
  for (int k = 0; k < 2; ++k) {
    for (int cls = -1; cls < kObjectClassCount; ++cls)
      side[k].dev_base[cls + 1] = block_deviance(side[k].base, side[k].held, blocks.n, side[k].g.cells(), cls);
    for (const auto& fr : side[k].held.frames) blocks.frames[fr.block] += 1, blocks.fold[fr.block] = k;
  }
  // A class's own candidates where both fit splits hold enough of its false positives for a window
  // (kWindowSide inside and outside); below that its table would be its fitting noise.
  PerClass<bool> own;
  own.fill(true);
  for (int k = 0; k < 2; ++k) {
    PerClass<long> n{};
    for (const auto& r : side[k].fit.fps) ++n[r.cls];
    for (int c = 0; c < kObjectClassCount; ++c) own[c] = own[c] && n[c] >= 2 * kFpWindowSide;
  }
  std::vector<std::array<FpModel, 2>> models;  // per candidate, per fold
  for (int f = 0; f < static_cast<int>(kFpFeatures.size()); ++f)
    for (bool window : {false, true})
      for (int cls = -1; cls < (f < kFpAttributeFeatures ? 3 : 0); ++cls) {
        if (cls >= 0 && !own[cls]) continue;
        std::array<FpModel, 2> fitted;
        FpCandidate c = judge_candidate(side, folds, blocks, f, window, false, cls, bins, fitted);
        c.fps = A.fps;
        A.candidates.push_back(c);
        models.push_back(std::move(fitted));
      }
  // The joint range x azimuth cell (object_fp_cell.h), for every class and for each class alone.
  for (int cls = -1; cls < kObjectClassCount; ++cls) {
    if (cls >= 0 && !own[cls]) continue;
    std::array<FpModel, 2> fitted;
    FpCandidate c = judge_candidate(side, folds, blocks, 0, false, true, cls, bins, fitted);
    c.fps = A.fps;
    A.candidates.push_back(c);
    models.push_back(std::move(fitted));
  }
  // The best candidate on an attribute of the false detection (what the KPI model's fp_table holds).
  for (size_t i = 0; i < A.candidates.size(); ++i) {
    const FpCandidate& c = A.candidates[i];
    if (c.feature < kFpAttributeFeatures && (A.added < 0 || c.score > A.candidates[A.added].score))
      A.added = static_cast<int>(i);
  }
  const int best = A.added;
  if (best >= 0) {
    const FpCandidate& b = A.candidates[best];
    if (!(b.score >= threshold && b.change[1] < 0)) A.added = -1;
  }
  for (size_t i = 0; i < A.candidates.size(); ++i) {
    FpCandidate& c = A.candidates[i];
    if (static_cast<int>(i) == A.added) c.decision = "added";
    else if (c.score < threshold) c.decision = "ruled out: held-out score below the threshold";
    else if (c.change[1] >= 0) c.decision = "rejected: the interval of the held-out deviance change reaches 0";
    else if (c.feature >= kFpAttributeFeatures)
      c.decision = "not addable: a frame feature (the KPI model's fp_table is over the false detection's attributes)";
    else c.decision = "not added: one false-positive table per run, the best first";
  }
  if (A.added >= 0) {
    // What the KPI manager draws with each fold's model, against the measured held-out rates.
    std::array<std::vector<std::array<double, 3>>, 2> sb, sa;
    for (int k = 0; k < 2; ++k) {
      sb[k] = simulated_pairs(data, folds[k], side[k], folds[k].base, seed);
      sa[k] = simulated_pairs(data, folds[k], side[k], with_fp_table(folds[k].base, models[A.added][k]), seed);
    }
    A.simulated_before = fp_rate_error(sb);
    A.simulated_after = fp_rate_error(sa);
  }
  // Ghost tracks: a candidate of its own (its own outcome), judged beside the rate tables.
  A.persistence = analyse_fp_persistence(data, folds, threshold, seed);
  return A;
}

sensor::KpiModel with_fitted_fp_table(const sensor::KpiModel& m, const Fold& whole, const FpCandidate& c, int bins) {
  const FpGrid g = fp_grid(whole.fit_set);
  const FpData fit = fp_data(whole.fit_set, g);
  const PerClass<double> floor = fp_floor(fit, g.cells());
  return with_fp_table(m, c.cell ? fit_fp_cell(fit, whole.base, bins, g, floor, c.cls)
                                 : fit_fp_model(fit, whole.base, c.feature, c.window, bins, g, floor, c.cls));
}

namespace {

// One rate candidate's entry in the report.
nlohmann::json fp_candidate_json(const FpCandidate& c) {
  return {{"feature", kFpFeatures[c.feature]},
          {"kind", c.cell ? "fp_rate_cell" : c.window ? "fp_rate_window" : "fp_rate_table"},
          {"class", c.cls < 0 ? std::string("all") : kObjectClasses[c.cls]},
          {"form_fold1", c.form},
          {"effect_size", c.effect_size},
          {"score", c.score},
          {"interval95", c.interval},
          {"significant", c.interval[0] > 0},
          {"change_interval95", c.change},
          {"deviance_before", c.deviance_before},
          {"deviance_after", c.deviance_after},
          {"error_before", c.error_before},
          {"error_after", c.error_after},
          {"decision", c.decision}};
}

// The persistence candidate as one more entry of the candidate list.
nlohmann::json fp_persistence_candidate_json(const FpPersistence& P) {
  std::ostringstream form;
  form << "ghost share x survival (fold 1)";
  for (int c = 0; c < kObjectClassCount; ++c)
    form << " " << kObjectClasses[c] << " " << fmt(P.classes[c].ghost_share, 3) << " x " << fmt(P.classes[c].survival, 3);
  form << "; jitter";
  for (int c = 0; c < kObjectClassCount; ++c) form << " " << fmt(P.classes[c].jitter, 3);
  form << " m; score_ar1";
  for (int c = 0; c < kObjectClassCount; ++c) form << " " << fmt(P.classes[c].score_ar1, 3);
  return {{"feature", "previous_frame"},
          {"kind", "fp_persistence"},
          {"form_fold1", form.str()},
          {"effect_size", P.effect_size},
          {"score", P.score},
          {"interval95", P.interval},
          {"significant", P.interval[0] > 0},
          {"change_interval95", P.change},
          {"error_metric", "persistence share error"},
          {"error_before", P.error_before},
          {"error_after", P.error_after},
          {"decision", P.decision}};
}

// Per class: the persistence fit and its measured / before / after statistics.
nlohmann::json fp_persistence_classes_json(const FpPersistence& P) {
  nlohmann::json pcl = nlohmann::json::object();
  // Total variation between two track-length distributions (shares per length bin).
  auto tv = [](const std::array<double, kFpTrackBins>& a, const std::array<double, kFpTrackBins>& b) {
    double d = 0;
    for (int l = 0; l < kFpTrackBins; ++l) d += std::abs(a[l] - b[l]);
    return 0.5 * d;
  };
  for (int c = 0; c < kObjectClassCount; ++c) {
    const FpPersistClass& k = P.classes[c];
    pcl[kObjectClasses[c]] = {{"held_out_false_positives", k.held_fps},
                              {"survival_fold1", k.survival},
                              {"ghost_share_fold1", k.ghost_share},
                              {"survival_fold2", P.survival[1][c]},
                              {"jitter_fold1", k.jitter},
                              {"score_ar1_fold1", k.score_ar1},
                              {"persistence_share", {{"measured", k.share_measured}, {"before", k.share_before}, {"after", k.share_after}}},
                              {"dispersion", {{"measured", k.dispersion_measured}, {"before", k.dispersion_before}, {"after", k.dispersion_after}}},
                              {"track_length_shares", {{"measured", k.tracks_measured}, {"before", k.tracks_before}, {"after", k.tracks_after}}},
                              {"mean_track_length", {{"measured", k.mean_track_measured}, {"before", k.mean_track_before}, {"after", k.mean_track_after}}},
                              {"track_length_tv", {{"before", tv(k.tracks_measured, k.tracks_before)}, {"after", tv(k.tracks_measured, k.tracks_after)}}}};
  }
  return pcl;
}

// The persistence section: its definitions, score and the per-class table.
nlohmann::json fp_persistence_json(const FpPersistence& P) {
  nlohmann::json pj = {
      {"outcome", "per held-out false positive: whether one of the same class lies within 1.5 m (BEV) in the previous "
                  "frame of its sequence (persistence share, per class)"},
      {"model", "per class fp_persistence fitted on the fit sequences: survival = sum max(0, L - 2) / sum (L - 1) over "
                "the false-positive tracks (greedy links within 1.5 m); ghost_share by bisection so that the KPI "
                "manager's false positives on the fit split's frames have the fit split's persistence share (if all "
                "ghosts fall short: ghost_share 1, survival by bisection); jitter = median |lateral step| / 0.6745 and "
                "score_ar1 = 2 sin(pi/6 Spearman) of linked pairs"},
      {"error_definition", "RMS over classes with >= 20 held-out false positives of the simulated (KPI manager, 4 seeds, "
                           "the fold's held-out ground truth) minus the measured persistence share; before: the fold's "
                           "base model, after: base plus fp_persistence"},
      {"score_definition", "1 - error_after / error_before; interval95 and change_interval95 (error_after - "
                           "error_before) by a basic bootstrap over the held-out 100-frame blocks; added when score >= "
                           "threshold and change_interval95 lies below 0"},
      {"track_length_bins", {"1", "2", "3-5", "6-10", "11-30", ">30"}},
      {"track_length_tv_definition", "total variation between the measured and simulated shares of tracks per length bin"},
      {"dispersion_definition", "variance / mean of the count per held-out frame (all held-out frames pooled)"},
      {"effect_size", P.effect_size},
      {"score", P.score},
      {"interval95", P.interval},
      {"change_interval95", P.change},
      {"error_before", P.error_before},
      {"error_after", P.error_after},
      {"added", P.added},
      {"model_term_on", "classes.*.fp_persistence"},
      {"classes", fp_persistence_classes_json(P)}};
  return pj;
}

// The added rate table, or null: its candidate's entry, in short, and the re-simulated errors.
nlohmann::json fp_added_json(const FpAnalysis& a) {
  if (a.added < 0) return nullptr;
  const nlohmann::json c = fp_candidate_json(a.candidates[a.added]);
  nlohmann::json j;
  for (const char* key : {"feature", "kind", "class", "score", "change_interval95", "error_before", "error_after"})
    j[key] = c[key];
  j["simulated_error_before"] = a.simulated_before, j["simulated_error_after"] = a.simulated_after;
  j["model_term_on"] = "classes.*.fp_table";
  return j;
}

}  // namespace

nlohmann::json fp_json(const FpAnalysis& a, double threshold) {
  nlohmann::json cj = nlohmann::json::array();
  for (const FpCandidate& c : a.candidates) cj.push_back(fp_candidate_json(c));
  cj.push_back(fp_persistence_candidate_json(a.persistence));
  nlohmann::json j = {
      {"outcome",
       "per block of 100 held-out frames, class and cell of a 5 x 5 x 4 grid over (range, azimuth, score) of the fit "
       "split's false positives (equal-count bins): the number of false positives, Poisson; the model's expected count "
       "per frame and cell from its rate and quantiles as the KPI manager samples them, summed over the block"},
      {"association", "a detection of a modelled class with score > 0 matched to no ground truth (same class, 2 m BEV "
                      "gate, Hungarian) and not within 2 m of other ground truth: lidar-calibrate's false positives"},
      {"score_definition", "1 - D_after / D_before, D the held-out Poisson deviance of each block's counts per class "
                           "and cell (blocks: 100 consecutive frames of a sequence; a class's own candidate: that class's "
                           "cells only), both folds; interval95 and "
                           "change_interval95 (deviance per frame, after - before) by a basic bootstrap over the blocks"},
      {"effect_size_definition", "fold 1: share of the expected false positives the candidate moves between cells "
                                 "(0.5 sum |mu_after - mu_before| / sum mu_before)"},
      {"error_definition", "false-positive rate error: RMS over class x cell of held-out false positives per frame minus "
                           "the model's expected count, beyond the held-out counts' Poisson noise (its variance "
                           "subtracted from the mean square; re-simulated: the simulated counts' too), both folds"},
      {"threshold", threshold},
      {"held_out_frames", a.frames},
      {"held_out_false_positives", a.fps},
      {"candidates", cj},
      {"persistence", fp_persistence_json(a.persistence)}};
  j["added"] = fp_added_json(a);
  return j;
}

std::string fp_markdown(const nlohmann::json& fp) {
  std::string md = "\n## False positives\n\nOutcome: " + fp["outcome"].get<std::string>() + ". Association: " +
                   fp["association"].get<std::string>() + ". Score: " + fp["score_definition"].get<std::string>() +
                   ". Held out: " + std::to_string(fp["held_out_frames"].get<int>()) + " frames, " +
                   std::to_string(fp["held_out_false_positives"].get<int>()) + " false positives.\n\n";
  if (fp["added"].is_null()) {
    md += "Added: **none**\n";
  } else {
    const auto& a = fp["added"];
    md += "Added: **" + a["feature"].get<std::string>() + "** (" + a["kind"].get<std::string>() + ", " +
          (a.value("class", "all") == "all" ? std::string("per class") : a.value("class", "") + " only") +
          " in `fp_table`): rate error " + fmt(a["error_before"].get<double>(), 4) + " -> " +
          fmt(a["error_after"].get<double>(), 4) + "; re-simulated by the KPI manager " +
          fmt(a["simulated_error_before"].get<double>(), 4) + " -> " + fmt(a["simulated_error_after"].get<double>(), 4) +
          "\n";
  }
  md += "\n| feature | kind | form (fold 1) | effect size | held-out score [95%] | deviance change per frame [95%] | "
        "deviance per frame before | after | rate error before | after | decision |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|\n";
  // The persistence row has no deviance: its error is the persistence share's, its change that error's.
  auto num = [&](const nlohmann::json& c, const char* k) { return c.contains(k) ? fmt(c[k].get<double>(), 4) : "—"; };
  for (const auto& c : fp["candidates"])
    md += "| " + c["feature"].get<std::string>() + " | " + c["kind"].get<std::string>() +
          (c.value("class", "all") == "all" ? std::string() : " (" + c.value("class", "") + ")") + " | " +
          c["form_fold1"].get<std::string>() + " | " + fmt(c["effect_size"].get<double>()) + " | " +
          fmt(c["score"].get<double>()) + " [" + fmt(c["interval95"][0].get<double>()) + ", " +
          fmt(c["interval95"][1].get<double>()) + "] | [" + fmt(c["change_interval95"][0].get<double>(), 4) + ", " +
          fmt(c["change_interval95"][1].get<double>(), 4) + "] | " + num(c, "deviance_before") + " | " +
          num(c, "deviance_after") + " | " + fmt(c["error_before"].get<double>(), 4) + " | " +
          fmt(c["error_after"].get<double>(), 4) + " | " + c["decision"].get<std::string>() + " |\n";
  if (fp.contains("persistence")) {
    const auto& p = fp["persistence"];
    md += "\n### Persistence (ghost tracks)\n\nOutcome: " + p["outcome"].get<std::string>() + ". Model: " +
          p["model"].get<std::string>() + ". Error: " + p["error_definition"].get<std::string>() + ". Score: " +
          p["score_definition"].get<std::string>() + ".\n\nAdded: **" + (p["added"].get<bool>() ? "yes" : "no") +
          "**; persistence share error " + fmt(p["error_before"].get<double>(), 4) + " -> " +
          fmt(p["error_after"].get<double>(), 4) + ", score " + fmt(p["score"].get<double>()) + " [" +
          fmt(p["interval95"][0].get<double>()) + ", " + fmt(p["interval95"][1].get<double>()) + "]\n\n" +
          (p.contains("plot") ? "![" + p["plot_caption"].get<std::string>() + "](" + p["plot"].get<std::string>() +
                                    ")\n\n"
                              : std::string()) +
          "| class | held-out FPs | ghost share x survival (fold 1); survival fold 2 | jitter m | score_ar1 | persistence share measured / before / after "
          "| dispersion measured / before / after | mean track length measured / before / after | single-frame tracks "
          "measured / before / after | track-length TV before / after |\n|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& [name, k] : p["classes"].items()) {
      auto three = [&](const nlohmann::json& v, int d) {
        return fmt(v["measured"].get<double>(), d) + " / " + fmt(v["before"].get<double>(), d) + " / " +
               fmt(v["after"].get<double>(), d);
      };
      const auto& t = k["track_length_shares"];
      md += "| " + name + " | " + std::to_string(k["held_out_false_positives"].get<long>()) + " | " +
            fmt(k["ghost_share_fold1"].get<double>(), 3) + " x " + fmt(k["survival_fold1"].get<double>(), 3) + "; " +
            fmt(k["survival_fold2"].get<double>(), 3) + " | " +
            fmt(k["jitter_fold1"].get<double>(), 3) + " | " + fmt(k["score_ar1_fold1"].get<double>(), 3) + " | " +
            three(k["persistence_share"], 3) + " | " + three(k["dispersion"], 2) + " | " +
            three(k["mean_track_length"], 2) + " | " + fmt(t["measured"][0].get<double>(), 3) + " / " +
            fmt(t["before"][0].get<double>(), 3) + " / " + fmt(t["after"][0].get<double>(), 3) + " | " +
            fmt(k["track_length_tv"]["before"].get<double>(), 3) + " / " + fmt(k["track_length_tv"]["after"].get<double>(), 3) +
            " |\n";
    }
  }
  return md;
}

std::string write_fp_tracks_png(const std::filesystem::path& path, const nlohmann::json& persistence) {
  // track_bin's bins are lengths 1, 2, 3-5, 6-10, 11-30, > 30: "at least L" for L = 2, 3, 6, 11, 31.
  static constexpr int kAtLeast[kFpTrackBins - 1] = {2, 3, 6, 11, 31};
  constexpr int kSlots = kFpTrackBins - 1, kGroup = kSlots + 1;  // one empty slot between classes
  const Rgb kAfter{60, 160, 60};
  struct Row {
    std::string name;
    std::array<double, kSlots> measured{}, before{}, after{};
  };
  std::vector<Row> rows;
  double top = 0;
  for (const auto& [name, k] : persistence.at("classes").items()) {
    Row r;
    r.name = name;
    const auto& t = k.at("track_length_shares");
    std::array<double, kSlots>* out[3] = {&r.measured, &r.before, &r.after};
    const char* which[3] = {"measured", "before", "after"};
    for (int w = 0; w < 3; ++w)
      for (int i = 0; i < kSlots; ++i) {
        double at_least = 0;
        for (int b = i + 1; b < kFpTrackBins; ++b) at_least += t.at(which[w]).at(b).get<double>();
        (*out[w])[i] = at_least;
        top = std::max(top, at_least);
      }
    rows.push_back(r);
  }
  ChartSpec spec;
  spec.title = "False-positive tracks on held-out sequences: share lasting at least L frames";
  spec.x_label = "L (frames), per class";
  spec.y_label = "share of false-positive tracks";
  spec.x_lo = -0.7, spec.x_hi = static_cast<double>(rows.size()) * kGroup - 1.3;
  spec.y_lo = 0, spec.y_hi = std::max(top, 1e-3) * 1.8;  // headroom: class names, then the legend above them
  for (size_t g = 0; g < rows.size(); ++g)
    for (int i = 0; i < kSlots; ++i) spec.x_ticks.push_back({static_cast<double>(g * kGroup + i), std::to_string(kAtLeast[i])});
  Chart chart(spec);
  for (size_t g = 0; g < rows.size(); ++g)
    for (int i = 0; i < kSlots; ++i) {
      const double x = static_cast<double>(g * kGroup + i);
      chart.bar(x - 0.32, x + 0.32, 0, rows[g].measured[i], kMeasured);
      chart.line(x - 0.42, rows[g].before[i], x + 0.42, rows[g].before[i], kSimulated, 4);
      chart.line(x - 0.42, rows[g].after[i], x + 0.42, rows[g].after[i], kAfter, 4);
    }
  chart.legend({{"measured", kMeasured, Mark::box},
                {"model before (a rate)", kSimulated, Mark::line},
                {"model after (ghost tracks)", kAfter, Mark::line}});
  Image image = chart.image();
  for (size_t g = 0; g < rows.size(); ++g) {
    const int cx = chart.px(static_cast<double>(g * kGroup) + (kSlots - 1) / 2.0);
    draw_text(image, cx - text_width(rows[g].name, 2) / 2, chart.py(std::max(top, 1e-3) * 1.12) - text_height(2),
              rows[g].name, {40, 40, 40}, 2);
  }
  write_png(path, image);
  return "Per class, the share of held-out false-positive tracks (same class within 1.5 m frame to frame) that last "
         "at least L frames: blue bars measured, orange marks the model before (a rate per frame), green marks the "
         "model with persistence; both models re-simulated on the held-out sequences with their fold's fit.";
}

}  // namespace lidarsim::qualify::obj
