// Persistence of false positives (ghost tracks): the statistics, the fit of the KPI model's
// fp_persistence on the fit sequences and its judgement on the held-out ones (object_false_positives.h).
#include <algorithm>
#include <cmath>
#include <numbers>

#include "qualify/objects/object_false_positives.h"
#include "qualify/similarity.h"
#include "sensor/kpi_fit.h"
#include "sensor/kpi_manager.h"

namespace lidarsim::qualify::obj {

namespace {

constexpr long kMinHeldFps = 20;   // a class enters the error with at least this many held-out false positives
constexpr long kMinPairs = 20;     // linked pairs a class needs for a jitter and score correlation of its own
constexpr int kFitSeeds = 4;       // the KPI manager's draws on the fit frames per bisection step
constexpr int kHeldSeeds = 4;      // re-simulations of the held-out sequences per model
constexpr int kBisection = 14;     // steps: survival to about 1e-4

int track_bin(int len) { return len <= 1 ? 0 : len == 2 ? 1 : len <= 5 ? 2 : len <= 10 ? 3 : len <= 30 ? 4 : 5; }

int block_of(const ObjectSet& s, size_t f) { return s.frame_seq[f] * 100000 + s.frame_index[f] / kFpBlockFrames; }

// Per class over the given sums: (persistence share, dispersion) and the false positives.
struct ClassSummary {
  double fps = 0, share = 0, dispersion = 0;
};
ClassSummary summarise(const std::array<double, 5>& s) {
  ClassSummary c;
  c.fps = s[0];
  c.share = s[0] > 0 ? s[1] / s[0] : 0;
  const double mean = s[2] > 0 ? s[3] / s[2] : 0, var = s[2] > 0 ? s[4] / s[2] - mean * mean : 0;
  c.dispersion = mean > 0 ? var / mean : 0;
  return c;
}

// RMS over the judged classes of simulated minus measured persistence share.
double share_error(const FpPersistSums& meas, const FpPersistSums& sim, const PerClass<bool>& judged) {
  double s = 0;
  int n = 0;
  for (int c = 0; c < kObjectClassCount; ++c) {
    if (!judged[c]) continue;
    const double d = summarise(sim[c]).share - summarise(meas[c]).share;
    s += d * d, ++n;
  }
  return n ? std::sqrt(s / n) : 0;
}

void add_to(FpPersistSums& a, const FpPersistSums& b, double w = 1) {
  for (int c = 0; c < kObjectClassCount; ++c)
    for (int k = 0; k < 5; ++k) a[c][k] += w * b[c][k];
}

FpPersistSums total(const FpPersistStats& st) {
  FpPersistSums t{};
  for (const auto& [b, s] : st.blocks) add_to(t, s);
  return t;
}

// The KPI manager's false positives alone (no truth) on the frames of `layout`, as records.
ObjectSet simulate_false_positives(const sensor::KpiModel& m, const ObjectSet& layout, std::uint64_t seed) {
  sensor::KpiOptions o;
  o.noise = o.misses = o.flips = false;
  sensor::KpiManager kpi(m, seed, o);
  ObjectSet out;
  out.frame_seq = layout.frame_seq;
  out.frame_index = layout.frame_index;
  std::vector<sensor::Object> none, rep;
  for (size_t f = 0; f < layout.frame_seq.size(); ++f) {
    kpi.apply(none, rep);
    for (const sensor::Object& d : rep) {
      if (d.id > -1000 || d.score <= 0) continue;  // the measured false positives have score > 0
      const auto it = std::find(kObjectClasses.begin(), kObjectClasses.end(), sensor::kpi_class_name(d.cls));
      if (it == kObjectClasses.end()) continue;
      out.fp_records.push_back({static_cast<int>(f), static_cast<int>(it - kObjectClasses.begin()),
                                d.position.head<2>().norm(), std::atan2(d.position.y(), d.position.x()), d.score});
    }
  }
  return out;
}

PerClass<double> shares_of(const FpPersistSums& t) {
  PerClass<double> out{};
  for (int c = 0; c < kObjectClassCount; ++c) out[c] = summarise(t[c]).share;
  return out;
}

PerClass<double> shares(const FpPersistStats& st) { return shares_of(total(st)); }

// The model with each class's persistence set (survival 0: none).
sensor::KpiModel with_persistence(sensor::KpiModel m, const PerClass<sensor::FalsePositivePersistence>& p) {
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it != m.classes.end()) it->second.fp_persistence = p[c].survival > 0 ? p[c] : sensor::FalsePositivePersistence{};
  }
  return m;
}

// The KPI manager's re-simulation of `held` (the other sequences left empty) with `model`, kHeldSeeds
// seeds; each block's sums divided by the seeds, and the tracks summed.
FpPersistStats simulated_stats(const TrackingData& data, const std::vector<int>& held, const sensor::KpiModel& model,
                               std::uint64_t seed) {
  std::vector<sensor::CalibrationSequence> only(data.calib.size());
  for (int s : held) only[s] = data.calib[s];
  for (size_t s = 0; s < only.size(); ++s)
    if (only[s].frames.empty()) only[s].name = data.calib[s].name;
  FpPersistStats out;
  for (int k = 0; k < kHeldSeeds; ++k) {
    const auto sim = sensor::resimulate(only, model, seed + 300 + k);
    const FpPersistStats st = fp_persist_stats(collect_objects(data, held, &sim));
    for (const auto& [b, s] : st.blocks) add_to(out.blocks[b], s, 1.0 / kHeldSeeds);
    for (int c = 0; c < kObjectClassCount; ++c)
      for (int l = 0; l < kFpTrackBins; ++l) out.tracks[c][l] += st.tracks[c][l];
  }
  return out;
}

// Spearman's rho of (score, previous score) over linked pairs.
double spearman_rho(const std::vector<std::array<double, 2>>& pairs) {
  auto ranks = [&](int k) {
    std::vector<size_t> idx(pairs.size());
    for (size_t i = 0; i < idx.size(); ++i) idx[i] = i;
    std::sort(idx.begin(), idx.end(), [&](size_t x, size_t y) { return pairs[x][k] < pairs[y][k]; });
    std::vector<double> r(idx.size());
    for (size_t i = 0; i < idx.size(); ++i) r[idx[i]] = static_cast<double>(i);
    return r;
  };
  const auto r0 = ranks(0), r1 = ranks(1);
  const double n = static_cast<double>(pairs.size()), mr = (n - 1) / 2;
  double sxy = 0, sxx = 0;
  for (size_t i = 0; i < pairs.size(); ++i) sxy += (r0[i] - mr) * (r1[i] - mr), sxx += (r0[i] - mr) * (r0[i] - mr);
  return sxx > 0 ? sxy / sxx : 0;
}

// Jitter and score correlation of one class from its linked pairs: the median |lateral step| as a
// normal step's sd, Spearman's rho as the correlation of a Gaussian copula.
void fit_jitter_and_score_ar1(const std::vector<double>& steps, const std::vector<std::array<double, 2>>& pairs,
                              sensor::FalsePositivePersistence& p) {
  std::vector<double> a(steps.size());
  for (size_t i = 0; i < steps.size(); ++i) a[i] = std::abs(steps[i]);
  std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
  p.jitter = a[a.size() / 2] / 0.6745;
  p.score_ar1 = std::clamp(2 * std::sin(std::numbers::pi / 6 * spearman_rho(pairs)), 0.0, 1.0);
}

// The persistence share per class of the manager's false positives on the fit frames under `q`,
// pooled over kFitSeeds draws.
PerClass<double> simulated_shares(const sensor::KpiModel& m, const ObjectSet& fit, std::uint64_t seed,
                                  const PerClass<sensor::FalsePositivePersistence>& q) {
  const sensor::KpiModel mm = with_persistence(m, q);
  FpPersistSums t{};
  for (int k = 0; k < kFitSeeds; ++k) add_to(t, total(fp_persist_stats(simulate_false_positives(mm, fit, seed + k))));
  return shares_of(t);
}

// The bisection for a target share per class, from `start` (survival from the runs, ghost share 1):
// the ghost share where every false positive as a ghost reaches the target, else the survival; a
// class whose share without persistence already reaches its target (or not `usable`) gets none.
PerClass<sensor::FalsePositivePersistence> solve_persistence(const sensor::KpiModel& m, const ObjectSet& fit,
                                                             std::uint64_t seed,
                                                             const PerClass<sensor::FalsePositivePersistence>& start,
                                                             const PerClass<bool>& usable,
                                                             const PerClass<double>& target) {
  PerClass<sensor::FalsePositivePersistence> p = start;
  PerClass<bool> fitted = usable;
  {
    auto none = p;
    for (auto& q : none) q.survival = 0;
    const auto at0 = simulated_shares(m, fit, seed, none);
    for (int c = 0; c < kObjectClassCount; ++c) fitted[c] = fitted[c] && at0[c] < target[c];
  }
  const auto at1 = simulated_shares(m, fit, seed, p);  // every false positive a ghost
  PerClass<bool> by_share{};
  PerClass<double> lo{}, hi{};
  for (int c = 0; c < kObjectClassCount; ++c) {
    by_share[c] = at1[c] >= target[c];
    lo[c] = by_share[c] ? 0.001 : p[c].survival;
    hi[c] = by_share[c] ? 1.0 : 0.95;
  }
  for (int it = 0; it < kBisection; ++it) {
    auto q = p;
    for (int c = 0; c < kObjectClassCount; ++c) {
      const double mid = 0.5 * (lo[c] + hi[c]);
      if (!fitted[c]) q[c].survival = 0;
      else if (by_share[c]) q[c].ghost_share = mid;
      else q[c].survival = mid;
    }
    const auto sh = simulated_shares(m, fit, seed, q);
    for (int c = 0; c < kObjectClassCount; ++c)
      if (fitted[c]) (sh[c] < target[c] ? lo[c] : hi[c]) = 0.5 * (lo[c] + hi[c]);
  }
  for (int c = 0; c < kObjectClassCount; ++c) {
    if (!fitted[c]) p[c].survival = 0;
    else if (by_share[c]) p[c].ghost_share = 0.5 * (lo[c] + hi[c]);
    else p[c].survival = 0.5 * (lo[c] + hi[c]);
  }
  for (int c = 0; c < kObjectClassCount; ++c) p[c].survival = fitted[c] ? p[c].survival : 0;
  return p;
}

// Jitter and score correlation from the fit split's linked pairs; survival by bisection so that the
// manager's false positives on the fit frames have the fit split's persistence share.
PerClass<sensor::FalsePositivePersistence> fit_persistence(const sensor::KpiModel& m, const TrackingData& data,
                                                                const std::vector<int>& fit_idx, const ObjectSet& fit,
                                                                std::uint64_t seed) {
  const FpPersistStats st = fp_persist_stats(fit);
  const PerClass<double> target = shares(st);
  PerClass<sensor::FalsePositivePersistence> p;
  for (int c = 0; c < kObjectClassCount; ++c)
    if (static_cast<long>(st.lateral_step[c].size()) >= kMinPairs)
      fit_jitter_and_score_ar1(st.lateral_step[c], st.score_pairs[c], p[c]);
  // Survival from the continuation of runs; then the ghost share (or, when all ghosts fall short, the
  // survival) by bisection on the persistence share of the manager's draws on the fit frames.
  PerClass<bool> fitted{};
  for (int c = 0; c < kObjectClassCount; ++c) {
    fitted[c] = static_cast<long>(st.lateral_step[c].size()) >= kMinPairs && st.links[c] > 0;
    p[c].survival = fitted[c] ? std::clamp(st.links2[c] / st.links[c], 0.05, 0.95) : 0;
    p[c].ghost_share = 1;
  }
  const PerClass<sensor::FalsePositivePersistence> start = p;
  p = solve_persistence(m, fit, seed, start, fitted, target);
  // The manager's false positives alone miss what the re-simulation adds (detections of the truth
  // placed beyond the gate count as false positives too, and never persist): scale the target by the
  // ratio of the re-simulated fit sequences' share to the false positives' own, then solve again.
  const FpPersistStats resim = simulated_stats(data, fit_idx, with_persistence(m, p), seed + 50);
  const PerClass<double> got = shares(resim);
  FpPersistSums own{};
  for (int k = 0; k < kFitSeeds; ++k)
    add_to(own, total(fp_persist_stats(simulate_false_positives(with_persistence(m, p), fit, seed + k))));
  PerClass<double> target2 = target;
  bool again = false;
  for (int c = 0; c < kObjectClassCount; ++c) {
    const double mine = summarise(own[c]).share;
    if (p[c].survival > 0 && got[c] > 0 && mine > 0) target2[c] = std::min(0.99, target[c] * mine / got[c]), again = true;
  }
  if (again) p = solve_persistence(m, fit, seed, start, fitted, target2);
  return p;
}

}  // namespace

FpPersistStats fp_persist_stats(const ObjectSet& set) {
  FpPersistStats st;
  const size_t nf = set.frame_seq.size();
  std::vector<size_t> order(set.fp_records.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return set.fp_records[a].slot < set.fp_records[b].slot; });
  std::vector<size_t> begin(nf + 1, 0);
  for (const auto& r : set.fp_records) ++begin[r.slot + 1];
  for (size_t f = 0; f < nf; ++f) begin[f + 1] += begin[f];
  auto xy = [&](size_t i) {
    const FalsePositiveRecord& r = set.fp_records[order[i]];
    return std::array<double, 2>{r.range * std::cos(r.azimuth), r.range * std::sin(r.azimuth)};
  };
  std::vector<int> len(order.size(), 0);
  std::vector<char> continued(order.size(), 0);
  auto close = [&](size_t f) {  // the tracks ending in frame f
    for (size_t i = begin[f]; i < begin[f + 1]; ++i)
      if (!continued[i]) {
        const int c = set.fp_records[order[i]].cls;
        st.tracks[c][track_bin(len[i])] += 1;
        st.links[c] += len[i] - 1;
        st.links2[c] += std::max(0, len[i] - 2);
      }
  };
  std::vector<std::array<double, 3>> pairs;  // (distance, this, previous)
  for (size_t f = 0; f < nf; ++f) {
    const bool linked = f > 0 && set.frame_seq[f - 1] == set.frame_seq[f] && set.frame_index[f - 1] + 1 == set.frame_index[f];
    if (f > 0 && !linked) close(f - 1);
    FpPersistSums& b = st.blocks[block_of(set, f)];
    PerClass<int> n{};
    pairs.clear();
    for (size_t i = begin[f]; i < begin[f + 1]; ++i) {
      const int c = set.fp_records[order[i]].cls;
      ++n[c];
      len[i] = 1;
      bool has = false;
      if (linked) {
        const auto p = xy(i);
        for (size_t j = begin[f - 1]; j < begin[f]; ++j) {
          if (set.fp_records[order[j]].cls != c) continue;
          const auto q = xy(j);
          const double d = std::hypot(p[0] - q[0], p[1] - q[1]);
          if (d > kFpPersistGate) continue;
          has = true;
          pairs.push_back({d, double(i), double(j)});
        }
      }
      b[c][1] += has;
    }
    // Tracks: nearest pairs first, one to one.
    std::sort(pairs.begin(), pairs.end());
    std::vector<char> taken_prev(linked ? begin[f] - begin[f - 1] : 0, 0), taken(begin[f + 1] - begin[f], 0);
    for (const auto& [d, fi, fj] : pairs) {
      const size_t i = static_cast<size_t>(fi), j = static_cast<size_t>(fj);
      if (taken[i - begin[f]] || taken_prev[j - begin[f - 1]]) continue;
      taken[i - begin[f]] = taken_prev[j - begin[f - 1]] = 1;
      continued[j] = 1;
      len[i] = len[j] + 1;
      const int c = set.fp_records[order[i]].cls;
      st.lateral_step[c].push_back(xy(i)[1] - xy(j)[1]);
      st.score_pairs[c].push_back({set.fp_records[order[i]].score, set.fp_records[order[j]].score});
    }
    if (linked) close(f - 1);
    for (int c = 0; c < kObjectClassCount; ++c) {
      b[c][0] += n[c];
      b[c][2] += 1;
      b[c][3] += n[c];
      b[c][4] += double(n[c]) * n[c];
    }
  }
  if (nf > 0) close(nf - 1);
  return st;
}

sensor::KpiModel with_fp_persistence(const sensor::KpiModel& m, const TrackingData& data, const std::vector<int>& fit_idx,
                                     const ObjectSet& fit, std::uint64_t seed) {
  sensor::KpiModel out = with_persistence(m, fit_persistence(m, data, fit_idx, fit, seed));
  out.source = m.source + "; plus the object loop's false-positive persistence";
  return out;
}

FpPersistence analyse_fp_persistence(const TrackingData& data, const std::array<Fold, 2>& folds, double threshold,
                                     std::uint64_t seed) {
  FpPersistence R;
  // Per held-out block: measured, simulated before, simulated after.
  std::map<int, std::array<FpPersistSums, 3>> blocks;
  std::array<PerClass<std::array<double, kFpTrackBins>>, 3> tracks{};  // which, class, bin
  for (int k = 0; k < 2; ++k) {
    const Fold& fold = folds[k];
    const auto p = fit_persistence(fold.base, data, fold.fit_idx, fold.fit_set, seed + 100 * k);
    for (int c = 0; c < kObjectClassCount; ++c) R.survival[k][c] = p[c].survival;
    if (k == 0) {
      double w = 0, sw = 0;
      for (int c = 0; c < kObjectClassCount; ++c) {
        R.classes[c].survival = p[c].survival, R.classes[c].ghost_share = p[c].ghost_share;
        R.classes[c].jitter = p[c].jitter, R.classes[c].score_ar1 = p[c].score_ar1;
        const auto it = fold.base.classes.find(kObjectClasses[c]);
        const double rate = it == fold.base.classes.end() ? 0 : it->second.false_positive_rate;
        w += rate, sw += rate * p[c].ghost_share * p[c].survival;
      }
      R.effect_size = w > 0 ? sw / w : 0;
    }
    const std::array<FpPersistStats, 3> st = {fp_persist_stats(fold.held_set),
                                              simulated_stats(data, fold.held_idx, fold.base, seed),
                                              simulated_stats(data, fold.held_idx, with_persistence(fold.base, p), seed)};
    for (int w = 0; w < 3; ++w) {
      for (const auto& [b, s] : st[w].blocks) add_to(blocks[b][w], s);
      for (int c = 0; c < kObjectClassCount; ++c)
        for (int l = 0; l < kFpTrackBins; ++l) tracks[w][c][l] += st[w].tracks[c][l];
    }
  }
  std::array<FpPersistSums, 3> all{};
  for (const auto& [b, v] : blocks)
    for (int w = 0; w < 3; ++w) add_to(all[w], v[w]);
  PerClass<bool> judged{};
  for (int c = 0; c < kObjectClassCount; ++c) {
    FpPersistClass& pc = R.classes[c];
    judged[c] = all[0][c][0] >= kMinHeldFps;
    pc.held_fps = static_cast<long>(all[0][c][0]);
    const ClassSummary m = summarise(all[0][c]), b = summarise(all[1][c]), a = summarise(all[2][c]);
    pc.share_measured = m.share, pc.share_before = b.share, pc.share_after = a.share;
    pc.dispersion_measured = m.dispersion, pc.dispersion_before = b.dispersion, pc.dispersion_after = a.dispersion;
    std::array<double, kFpTrackBins>* out[3] = {&pc.tracks_measured, &pc.tracks_before, &pc.tracks_after};
    double* mean[3] = {&pc.mean_track_measured, &pc.mean_track_before, &pc.mean_track_after};
    for (int w = 0; w < 3; ++w) {
      double n = 0;
      for (double v : tracks[w][c]) n += v;
      for (int l = 0; l < kFpTrackBins; ++l) (*out[w])[l] = n > 0 ? tracks[w][c][l] / n : 0;
      // Every false positive is in one track: mean length = false positives / tracks (simulated: per seed).
      *mean[w] = n > 0 ? all[w][c][0] * (w == 0 ? 1.0 : kHeldSeeds) / n : 0;
    }
  }
  R.error_before = share_error(all[0], all[1], judged);
  R.error_after = share_error(all[0], all[2], judged);
  R.score = R.error_before > 0 ? 1 - R.error_after / R.error_before : 0;
  // Basic bootstrap over the held-out blocks, the measured and simulated sums of a block together.
  std::vector<const std::array<FpPersistSums, 3>*> list;
  for (const auto& [b, v] : blocks) list.push_back(&v);
  if (!list.empty()) {
    SplitMix rng(11);
    std::vector<double> rs, rc;
    for (int r = 0; r < 1000; ++r) {
      std::array<FpPersistSums, 3> s{};
      for (size_t j = 0; j < list.size(); ++j) {
        const auto& v = *list[rng.next() % list.size()];
        for (int w = 0; w < 3; ++w) add_to(s[w], v[w]);
      }
      const double eb = share_error(s[0], s[1], judged), ea = share_error(s[0], s[2], judged);
      rs.push_back(eb > 0 ? 1 - ea / eb : 0);
      rc.push_back(ea - eb);
    }
    auto basic = [](std::vector<double>& v, double point) {
      std::sort(v.begin(), v.end());
      const auto q = [&](double p) { return v[static_cast<size_t>(p * (v.size() - 1))]; };
      return std::array<double, 2>{2 * point - q(0.975), 2 * point - q(0.025)};
    };
    R.interval = basic(rs, R.score);
    R.change = basic(rc, R.error_after - R.error_before);
  }
  R.added = R.score >= threshold && R.change[1] < 0;
  R.decision = R.added                ? "added"
               : R.score < threshold ? "ruled out: held-out score below the threshold"
                                     : "rejected: the interval of the held-out error change reaches 0";
  return R;
}

}  // namespace lidarsim::qualify::obj
