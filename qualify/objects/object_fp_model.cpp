// The false-positive models of the object loop (object_false_positives.h): the grid, a set's counts,
// the base model's and the candidates' expected counts per cell, their Poisson deviance, and the
// KPI model's fp_table written from a candidate.
#include <algorithm>
#include <cmath>
#include <numeric>

#include "qualify/objects/object_false_positives.h"
#include "qualify/windows.h"

namespace lidarsim::qualify::obj {

namespace {

constexpr double kPriorWeight = 20;  // pseudo false positives a bin's placement is shrunk with

std::vector<double> quantiles(std::vector<double> v) {
  if (v.size() < 2) return {};
  std::sort(v.begin(), v.end());
  std::vector<double> q(kFpQuantiles);
  for (int i = 0; i < kFpQuantiles; ++i) {
    const double x = double(i) / (kFpQuantiles - 1) * (v.size() - 1);
    const size_t k = std::min(static_cast<size_t>(x), v.size() - 2);
    q[i] = v[k] + (x - k) * (v[k + 1] - v[k]);
  }
  return q;
}

// P(X < x) for X sampled as the KPI manager does: uniform between neighbouring quantiles.
double quantile_cdf(const std::vector<double>& q, double x) {
  if (q.size() < 2) return x > 0 ? 1 : 0;  // no quantiles: the manager's fallback is one value; not used
  if (x <= q.front()) return 0;
  if (x >= q.back()) return 1;
  const size_t i = static_cast<size_t>(std::upper_bound(q.begin(), q.end(), x) - q.begin()) - 1;
  return (static_cast<double>(i) + (x - q[i]) / (q[i + 1] - q[i])) / static_cast<double>(q.size() - 1);
}

// Probability of each bin of `cuts` under the quantiles.
std::vector<double> bin_probabilities(const std::vector<double>& q, const std::vector<double>& cuts) {
  std::vector<double> p(cuts.size() + 1);
  double prev = 0;
  for (size_t k = 0; k < cuts.size(); ++k) {
    const double c = quantile_cdf(q, cuts[k]);
    p[k] = c - prev;
    prev = c;
  }
  p.back() = 1 - prev;
  return p;
}

double feature_of(const FalsePositiveRecord& r, int feature) {
  return feature == 0 ? r.range : feature == 1 ? r.azimuth : r.score;
}

}  // namespace

int FpGrid::cells() const { return static_cast<int>((range.size() + 1) * (azimuth.size() + 1) * (score.size() + 1)); }

int FpGrid::cell(double r, double a, double s) const {
  return (fp_cut_bin(range, r) * static_cast<int>(azimuth.size() + 1) + fp_cut_bin(azimuth, a)) *
             static_cast<int>(score.size() + 1) +
         fp_cut_bin(score, s);
}

FpGrid fp_grid(const ObjectSet& fit) {
  std::vector<double> r, a, s;
  for (const auto& f : fit.fp_records) r.push_back(f.range), a.push_back(f.azimuth), s.push_back(f.score);
  FpGrid g;
  if (r.size() < 40) return g;  // too few for cells: one cell
  g.range = equal_count_edges(r, 5);
  g.azimuth = equal_count_edges(a, 5);
  g.score = equal_count_edges(s, 4);
  return g;
}

FpData fp_data(const ObjectSet& set, const FpGrid& g) {
  FpData d;
  d.frames.resize(set.frame_seq.size());
  for (size_t f = 0; f < d.frames.size(); ++f) {
    d.frames[f].block = set.frame_seq[f] * 100000 + set.frame_index[f] / kFpBlockFrames;
    d.frames[f].feature = {double(set.frame_truths[f]), double(set.frame_index[f])};
  }
  d.fps = set.fp_records;
  for (const auto& r : d.fps) {
    auto& c = d.frames[r.slot].counts;
    const int cell = g.cell(r.range, r.azimuth, r.score);
    auto it = std::find_if(c.begin(), c.end(), [&](const auto& e) { return e[0] == r.cls && e[1] == cell; });
    if (it == c.end()) c.push_back({r.cls, cell, 1});
    else ++(*it)[2];
  }
  return d;
}

int FpModel::frame_bin(const FpData::Frame& f) const {
  if (feature < kFpAttributeFeatures) return 0;
  return fp_cut_bin(cuts, f.feature[feature - kFpAttributeFeatures]);
}

void FpModel::compile(const FpGrid& g, const PerClass<double>& floor) {
  const int nr = static_cast<int>(g.range.size() + 1), na = static_cast<int>(g.azimuth.size() + 1),
            ns = static_cast<int>(g.score.size() + 1);
  const bool frame_feature = feature >= kFpAttributeFeatures;
  for (int c = 0; c < kObjectClassCount; ++c) {
    mu[c].assign(frame_feature ? comps[c].size() : 1, std::vector<double>(g.cells(), floor[c]));
    for (size_t b = 0; b < comps[c].size(); ++b) {
      const FpComponent& k = comps[c][b];
      if (k.rate <= 0) continue;
      auto& m = mu[c][frame_feature ? b : 0];
      const auto pr = bin_probabilities(k.rq, g.range), pa = bin_probabilities(k.aq, g.azimuth),
                 ps = bin_probabilities(k.sq, g.score);
      for (int i = 0; i < nr; ++i)
        for (int j = 0; j < na; ++j)
          for (int l = 0; l < ns; ++l) m[(i * na + j) * ns + l] += k.rate * pr[i] * pa[j] * ps[l];
    }
    if (mu[c].empty()) mu[c].assign(1, std::vector<double>(g.cells(), floor[c]));
  }
}

FpModel fp_base(const sensor::KpiModel& base) {
  FpModel m;
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = base.classes.find(kObjectClasses[c]);
    FpComponent k;
    if (it != base.classes.end()) {
      const sensor::ClassModel& cm = it->second;
      k = {cm.false_positive_rate, cm.fp_range_quantiles, cm.fp_azimuth_quantiles, cm.fp_score_quantiles};
    }
    m.comps[c] = {k};
  }
  return m;
}

FpModel fp_base(const sensor::KpiModel& base, const FpData& fit) {
  FpModel m = fp_base(base);
  PerClass<std::vector<double>> r, a, s;
  for (const auto& f : fit.fps) r[f.cls].push_back(f.range), a[f.cls].push_back(f.azimuth), s[f.cls].push_back(f.score);
  const double frames = static_cast<double>(std::max<size_t>(1, fit.frames.size()));
  for (int c = 0; c < kObjectClassCount; ++c)
    if (!base.classes.count(kObjectClasses[c]) && r[c].size() >= 2)
      m.comps[c] = {{r[c].size() / frames, quantiles(r[c]), quantiles(a[c]), quantiles(s[c])}};
  return m;
}

PerClass<double> fp_floor(const FpData& fit, int cells) {
  PerClass<double> n{};
  for (const auto& r : fit.fps) n[r.cls] += 1;
  PerClass<double> out{};
  const double frames = std::max<size_t>(1, fit.frames.size());
  for (int c = 0; c < kObjectClassCount; ++c) out[c] = 1e-3 * std::max(n[c], 1.0) / frames / cells;
  return out;
}

std::vector<double> fp_deviance(const FpModel& m, const FpData& d) {
  // Per class and bin: the sum of the expected counts over the cells.
  PerClass<std::vector<double>> total;
  for (int c = 0; c < kObjectClassCount; ++c)
    for (const auto& cells : m.mu[c]) total[c].push_back(std::accumulate(cells.begin(), cells.end(), 0.0));
  std::vector<double> dev(d.frames.size());
  for (size_t f = 0; f < d.frames.size(); ++f) {
    const auto& fr = d.frames[f];
    const int b = m.frame_bin(fr);
    double s = 0;
    for (int c = 0; c < kObjectClassCount; ++c) s += total[c][std::min<size_t>(b, total[c].size() - 1)];
    for (const auto& [c, cell, y] : fr.counts) {
      const double mu = m.mu[c][std::min<size_t>(b, m.mu[c].size() - 1)][cell];
      s += y * std::log(double(y)) - y * std::log(mu) - y;
    }
    dev[f] = 2 * s;
  }
  return dev;
}

namespace {

// Quantiles of `own` (weight 1 each) pooled with `ref` (kPriorWeight in all), both sorted: a bin's
// placement shrunk toward a reference. A bin's own few false positives span less than the class's:
// with their quantiles alone every held-out false positive beyond that span lands where the model has
// nothing (only the floor, ~20 deviance units each), a loss that outweighs what a table or window
// gains held-out.
std::vector<double> shrunk_quantiles(const std::vector<double>& own, const std::vector<double>& ref) {
  if (own.size() + ref.size() < 2) return {};
  // Merged in (value, weight) order, as sorting the pooled pairs would put them: the window search
  // calls this for every bin of ~800 windows, so it must stay linear (a sort per call would
  // dominate the loop's time).
  const double w = kPriorWeight / static_cast<double>(ref.size());
  std::vector<std::pair<double, double>> v;  // value, weight
  v.reserve(own.size() + ref.size());
  size_t i = 0, j = 0;
  while (i < own.size() || j < ref.size()) {
    const bool take_own = j == ref.size() ||
                          (i < own.size() && std::pair(own[i], 1.0) < std::pair(ref[j], w));
    if (take_own) v.push_back({own[i++], 1.0});
    else v.push_back({ref[j++], w});
  }
  // Point k at t_k = (weight before it + half its own - half the first's) / (total - half the ends'):
  // with equal weights k / (n - 1), as quantiles() places them.
  std::vector<double> t(v.size());
  double before = 0;
  for (size_t k = 0; k < v.size(); ++k) t[k] = before + v[k].second / 2, before += v[k].second;
  const double lo = t.front(), span = t.back() - t.front();
  std::vector<double> q(kFpQuantiles);
  size_t k = 0;
  for (int n = 0; n < kFpQuantiles; ++n) {
    const double p = lo + span * n / (kFpQuantiles - 1);
    while (k + 2 < v.size() && t[k + 1] < p) ++k;
    const double f = t[k + 1] > t[k] ? std::clamp((p - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0) : 0.0;
    q[n] = v[k].first + f * (v[k + 1].first - v[k].first);
  }
  return q;
}

// What every candidate of one fit_fp_model call shares: the base, and the false positives in the
// order of each attribute (so a bin's values come out sorted) with each class's sorted values.
struct FpFitContext {
  FpModel b0;
  std::array<std::vector<size_t>, kFpAttributeFeatures> order;
  PerClass<std::array<std::vector<double>, kFpAttributeFeatures>> all;  // per class, attribute
};

FpFitContext fit_context(const FpData& fit, const sensor::KpiModel& base) {
  FpFitContext ctx;
  ctx.b0 = fp_base(base, fit);
  for (int a = 0; a < kFpAttributeFeatures; ++a) {
    auto& o = ctx.order[a];
    o.resize(fit.fps.size());
    std::iota(o.begin(), o.end(), size_t{0});
    std::stable_sort(o.begin(), o.end(),
                     [&](size_t x, size_t y) { return feature_of(fit.fps[x], a) < feature_of(fit.fps[y], a); });
    for (size_t i : o) ctx.all[fit.fps[i].cls][a].push_back(feature_of(fit.fps[i], a));
  }
  return ctx;
}

// Per class and bin of an attribute (m.feature, m.cuts): a rate and a placement. The placement is
// the bin's own false positives of the class shrunk toward, for the binned attribute, the bin's of
// every class (where in the bin) and for the other two, the class's over all bins (its marginal).
// cls >= 0: that class only (a class's own candidate; the others keep the base's, set by the caller).
void attribute_components(FpModel& m, const FpData& fit, const FpFitContext& ctx, int cls) {
  const int nb = static_cast<int>(m.cuts.size() + 1);
  std::vector<int> bin(fit.fps.size());
  for (size_t i = 0; i < fit.fps.size(); ++i) bin[i] = fp_cut_bin(m.cuts, feature_of(fit.fps[i], m.feature));
  std::vector<std::array<std::vector<double>, kFpAttributeFeatures>> pooled(nb);
  PerClass<std::vector<std::array<std::vector<double>, kFpAttributeFeatures>>> own;
  for (auto& v : own) v.resize(nb);
  for (int a = 0; a < kFpAttributeFeatures; ++a)
    for (size_t i : ctx.order[a]) {
      const FalsePositiveRecord& r = fit.fps[i];
      const double x = feature_of(r, a);
      if (a == m.feature) pooled[bin[i]][a].push_back(x);
      own[r.cls][bin[i]][a].push_back(x);
    }
  const double frames = std::max<size_t>(1, fit.frames.size());
  for (int c = 0; c < kObjectClassCount; ++c)
    for (int b = 0; b < nb && (cls < 0 || c == cls); ++b) {
      FpComponent k;
      k.rate = own[c][b][0].size() / frames;
      std::array<std::vector<double>, kFpAttributeFeatures> q;
      for (int a = 0; a < kFpAttributeFeatures; ++a)
        q[a] = shrunk_quantiles(own[c][b][a], a == m.feature ? pooled[b][a] : ctx.all[c][a]);
      // The binned attribute's placement reaches the bin's edges (the KPI manager draws between them).
      auto& qf = q[m.feature];
      if (!qf.empty() && b > 0) qf.front() = std::min(qf.front(), m.cuts[b - 1]);
      if (!qf.empty() && b < nb - 1) qf.back() = std::max(qf.back(), m.cuts[b]);
      k.rq = q[0], k.aq = q[1], k.sq = q[2];
      // Nowhere to place them, or a class without false positives to model (< 2 on the fit split).
      if (k.rq.empty() || k.aq.empty() || k.sq.empty() || ctx.b0.comps[c][0].rq.empty()) k.rate = 0;
      m.comps[c].push_back(k);
    }
}

// Components of a candidate with the given cuts, fitted on `fit`, for every class (an attribute's:
// for class cls only when cls >= 0).
FpModel class_components(const FpData& fit, const FpFitContext& ctx, int feature, const std::vector<double>& cuts,
                         int cls) {
  FpModel m;
  m.feature = feature;
  m.cuts = cuts;
  const int nb = static_cast<int>(cuts.size() + 1);
  const FpModel& b0 = ctx.b0;
  if (feature >= kFpAttributeFeatures) {
    // A rate per frame bin; the class's placement.
    std::vector<double> frames(nb, 0.0);
    PerClass<std::vector<double>> n;
    for (auto& v : n) v.assign(nb, 0.0);
    for (const auto& f : fit.frames) frames[m.frame_bin(f)] += 1;
    for (const auto& r : fit.fps) n[r.cls][m.frame_bin(fit.frames[r.slot])] += 1;
    for (int c = 0; c < kObjectClassCount; ++c)
      for (int b = 0; b < nb; ++b) {
        FpComponent k = b0.comps[c][0];
        k.rate = frames[b] > 0 && !k.rq.empty() && !k.aq.empty() ? n[c][b] / frames[b] : 0;
        m.comps[c].push_back(k);
      }
    return m;
  }
  attribute_components(m, fit, ctx, cls);
  return m;
}

// The same for class `cls` only (>= 0): the other classes keep the base's component.
FpModel components(const FpData& fit, const FpFitContext& ctx, int feature, const std::vector<double>& cuts,
                   int cls) {
  FpModel m = class_components(fit, ctx, feature, cuts, cls);
  if (cls < 0) return m;
  for (int c = 0; c < kObjectClassCount; ++c)
    if (c != cls) m.comps[c] = ctx.b0.comps[c];
  m.cls = cls;
  return m;
}

std::vector<double> feature_values(const FpData& fit, int feature, int cls) {
  std::vector<double> x;
  if (feature < kFpAttributeFeatures) {
    for (const auto& r : fit.fps)
      if (cls < 0 || r.cls == cls) x.push_back(feature_of(r, feature));
  } else {
    for (const auto& f : fit.frames) x.push_back(f.feature[feature - kFpAttributeFeatures]);
  }
  return x;
}

}  // namespace

FpModel fit_fp_model(const FpData& fit, const sensor::KpiModel& base, int feature, bool window, int bins,
                     const FpGrid& g, const PerClass<double>& floor, int cls) {
  const std::vector<double> x = feature_values(fit, feature, cls);
  const FpFitContext ctx = fit_context(fit, base);
  if (!window) {
    FpModel m = components(fit, ctx, feature, equal_count_edges(x, bins), cls);
    m.compile(g, floor);
    return m;
  }
  // The window (or step) of the fine bins whose model has the lowest deviance on the fit split. The
  // window must hold kFpWindowSide false positives; outside it may hold few: a cell that holds most
  // of a class's false positives leaves few beside it, and a window forced to leave 30 outside cut
  // the cell in two (a fine bin, 1/20 of them, is always outside).
  const std::vector<double> fine = equal_count_edges(x, 2 * bins);
  const int K = static_cast<int>(fine.size() + 1);
  std::vector<long> cum(K + 1, 0);
  for (double v : x) ++cum[fp_cut_bin(fine, v) + 1];
  for (int k = 0; k < K; ++k) cum[k + 1] += cum[k];
  FpModel best = ctx.b0;
  best.compile(g, floor);
  const auto d0 = fp_deviance(best, fit);
  double best_dev = std::accumulate(d0.begin(), d0.end(), 0.0);
  bool found = false;
  for (int a = 0; a < K; ++a)
    for (int b = a; b < K; ++b) {
      if (a == 0 && b == K - 1) continue;
      const long in = cum[b + 1] - cum[a], out = cum[K] - in;
      if (in < kFpWindowSide || out < 1) continue;
      std::vector<double> cuts;
      if (a > 0) cuts.push_back(fine[a - 1]);
      if (b < K - 1) cuts.push_back(fine[b]);
      FpModel m = components(fit, ctx, feature, cuts, cls);
      m.compile(g, floor);
      const auto d = fp_deviance(m, fit);
      const double dev = std::accumulate(d.begin(), d.end(), 0.0);
      if (dev < best_dev) best_dev = dev, best = std::move(m), found = true;
    }
  if (!found) best.feature = feature, best.cls = cls;  // no window qualifies: the base
  return best;
}

sensor::KpiModel with_fp_table(const sensor::KpiModel& base, const FpModel& fp) {
  sensor::KpiModel m = base;
  if (fp.feature < 0 || fp.feature >= kFpAttributeFeatures) return m;
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it == m.classes.end() || (fp.cls >= 0 && c != fp.cls)) continue;
    sensor::FalsePositiveTable t;
    t.feature = kFpFeatures[fp.feature];
    // Lower edges: the model's first bin takes everything below its second edge.
    t.edges.push_back(fp.cuts.empty() ? 0.0 : fp.cuts.front() - 1);
    t.edges.insert(t.edges.end(), fp.cuts.begin(), fp.cuts.end());
    for (const FpComponent& k : fp.comps[c]) {
      t.rate.push_back(k.rate);
      t.range_quantiles.push_back(k.rq);
      t.azimuth_quantiles.push_back(k.aq);
      t.score_quantiles.push_back(k.sq);
    }
    if (t.rate.size() != t.edges.size()) continue;  // the base (no cuts, one component): no table
    it->second.fp_table = t;
  }
  m.source = base.source + "; plus the object loop's false-positive table on " + kFpFeatures[fp.feature] +
             (fp.cls >= 0 ? " (" + kObjectClasses[fp.cls] + ")" : "");
  return m;
}

}  // namespace lidarsim::qualify::obj
