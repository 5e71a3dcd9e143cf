#include "qualify/object_terms.h"

#include <algorithm>

namespace lidarsim::qualify::obj {

ClassTables fit_class_tables(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                             int bins) {
  ClassTables t;
  t.pooled = fit_binned_mean(x, r, bins);
  for (int c = 0; c < 3; ++c) {
    std::vector<double> xc, rc;
    for (size_t i = 0; i < x.size(); ++i)
      if (cls[i] == c) xc.push_back(x[i]), rc.push_back(r[i]);
    if (xc.size() >= 200) t.per_class[c] = fit_binned_mean(xc, rc, bins), t.own[c] = true;
  }
  return t;
}

Refit backfit(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
              const std::vector<int>& rb, int bins) {
  Refit f;
  std::vector<double> y(r.size());
  for (int pass = 0; pass < 4; ++pass) {
    for (size_t i = 0; i < r.size(); ++i) {
      const auto it = f.d.find({cls[i], rb[i]});
      y[i] = r[i] - (it == f.d.end() ? 0.0 : it->second);
    }
    f.table = fit_class_tables(x, y, cls, bins);
    std::map<std::pair<int, int>, std::pair<double, long>> acc;
    for (size_t i = 0; i < r.size(); ++i) {
      auto& a = acc[{cls[i], rb[i]}];
      a.first += r[i] - f.table(cls[i], x[i]);
      ++a.second;
    }
    f.d.clear();
    for (const auto& [k, a] : acc)
      if (a.second >= 20) f.d[k] = a.first / a.second;
  }
  return f;
}

BinnedTable fit_window(const std::vector<double>& x, const std::vector<double>& y, int fine_bins, long min_side) {
  const BinnedTable fine = fit_binned_mean(x, y, fine_bins, 0);
  const int K = static_cast<int>(fine.value.size());
  std::vector<double> S(K + 1, 0.0);
  std::vector<long> N(K + 1, 0);
  for (int b = 0; b < K; ++b) S[b + 1] = S[b] + fine.value[b] * fine.count[b], N[b + 1] = N[b] + fine.count[b];
  const long n = N[K];
  double best = 0;
  int bi = -1, bj = -1;
  for (int i = 0; i < K; ++i)
    for (int j = i; j < K; ++j) {
      if (i == 0 && j == K - 1) continue;
      const long n_in = N[j + 1] - N[i], n_out = n - n_in;
      if (n_in < min_side || n_out < min_side) continue;
      // A step is the same split as its complement: keep the smaller side as the run, so the
      // term's bias sits where the effect is and the model's cells carry the rest.
      if ((i == 0 || j == K - 1) && 2 * n_in > n) continue;
      const double s_in = S[j + 1] - S[i], d = s_in / n_in - (S[K] - s_in) / n_out;
      const double between = d * d * double(n_in) * double(n_out) / double(n);
      if (between > best) best = between, bi = i, bj = j;
    }
  BinnedTable w;
  if (bi < 0) {
    w.value = {0.0};
    w.count = {n};
    return w;
  }
  const long n_in = N[bj + 1] - N[bi];
  const double s_in = S[bj + 1] - S[bi];
  const double delta = (s_in / n_in - (S[K] - s_in) / (n - n_in)) * n_in / (n_in + 5.0);
  if (bi > 0) w.edges.push_back(fine.edges[bi - 1]), w.value.push_back(0), w.count.push_back(N[bi]);
  w.value.push_back(delta), w.count.push_back(n_in);
  if (bj < K - 1) w.edges.push_back(fine.edges[bj]), w.value.push_back(0), w.count.push_back(n - N[bj + 1]);
  return w;
}

Refit backfit_window(const std::vector<double>& x, const std::vector<double>& r, const std::vector<int>& cls,
                     const std::vector<int>& rb, int fine_bins) {
  Refit f;
  std::vector<double> y(r.size());
  for (int pass = 0; pass < 4; ++pass) {
    for (size_t i = 0; i < r.size(); ++i) {
      const auto it = f.d.find({cls[i], rb[i]});
      y[i] = r[i] - (it == f.d.end() ? 0.0 : it->second);
    }
    f.table = ClassTables{};
    f.table.pooled = fit_window(x, y, fine_bins);
    std::map<std::pair<int, int>, std::pair<double, long>> acc;
    for (size_t i = 0; i < r.size(); ++i) {
      auto& a = acc[{cls[i], rb[i]}];
      a.first += r[i] - f.table(cls[i], x[i]);
      ++a.second;
    }
    f.d.clear();
    for (const auto& [k, a] : acc)
      if (a.second >= 20) f.d[k] = a.first / a.second;
  }
  return f;
}

void shrink_noise_for_term(sensor::KpiModel& m, const Refit& ref, int t, const std::string& feature, const Split& fit,
                           const Winsor& w, int nvis, std::array<bool, 3> classes) {
  if (t == kDetectionTarget) return;
  const bool track_constant =
      feature == "size" || feature == "box_width" || feature == "box_height" || feature == "class";
  const auto x = fit.column(feature_index(feature));
  const auto cls = fit.classes();
  const auto cells = fit.cells(t, nvis);
  const auto r = fit.clipped(w);
  for (int c = 0; c < 3; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it == m.classes.end() || !classes[c]) continue;
    std::vector<double> vals, res;
    for (size_t i = 0; i < x.size(); ++i)
      if (cls[i] == c) vals.push_back(ref(c, cells[i], x[i])), res.push_back(r[i]);
    if (vals.size() < 20) continue;
    auto var = [](const std::vector<double>& v) {
      const double m = mean_of(v);
      double s = 0;
      for (double a : v) s += (a - m) * (a - m);
      return s / v.size();
    };
    const double V = var(res);
    double v = var(vals);
    if (V <= 0 || v <= 0) continue;
    sensor::ErrorModel& em = it->second.errors[int(kTargetParam[t])];
    if (track_constant) {
      const double take = std::min(v, em.track_std * em.track_std);
      em.track_std = std::sqrt(em.track_std * em.track_std - take);
      v -= take;
    }
    const double f = std::sqrt(std::max(0.04, 1 - v / V));
    for (double& s : em.sigma) s *= f;
  }
}

double refit_probability(const Refit& ref, int cls, int cell, double x, double p) {
  const auto it = ref.d.find({cls, cell});
  const double q = std::clamp(p + (it == ref.d.end() ? 0.0 : it->second), 0.0, 1.0);
  return std::clamp(q + std::clamp(ref.table(cls, x), -1.0, 1.0), 0.0, 1.0);
}

Refit refit_on(const Fold& k, int t, int f, int nvis, int bins) {
  const Split& s = k.fit_r[t];
  return backfit(s.column(f), s.clipped(k.win[t]), s.classes(), s.cells(t, nvis), bins);
}

sensor::KpiModel with_term(const sensor::KpiModel& base, const Refit& ref, int t, const std::string& feature,
                           int nvis, std::array<bool, 3> classes) {
  sensor::KpiModel m = base;
  for (int c = 0; c < 3; ++c) {
    const auto it = m.classes.find(kObjectClasses[c]);
    if (it == m.classes.end() || !classes[c]) continue;
    sensor::ClassModel& cm = it->second;
    const BinnedTable& bt = ref.table.own[c] ? ref.table.per_class[c] : ref.table.pooled;
    // BinnedTable cut points -> the term's lower edges (bin 0 takes everything below edges[1]).
    sensor::ConditionalTerm ct;
    ct.feature = feature;
    ct.edges.push_back(bt.edges.empty() ? 0.0 : bt.edges.front() - 1);
    ct.edges.insert(ct.edges.end(), bt.edges.begin(), bt.edges.end());
    ct.bias = bt.value;
    if (t == kDetectionTarget) {
      for (int rb = 0; rb < static_cast<int>(cm.detection_probability.size()); ++rb)
        for (int vb = 0; vb < static_cast<int>(cm.detection_probability[rb].size()); ++vb) {
          const auto d = ref.d.find({c, rb * nvis + vb});
          double& p = cm.detection_probability[rb][vb];
          if (d != ref.d.end()) p = std::clamp(p + d->second, 0.0, 1.0);
        }
      for (double& b : ct.bias) b = std::clamp(b, -1.0, 1.0);  // a probability shift
      cm.detection_conditional = ct;
    } else {
      sensor::ErrorModel& em = cm.errors[int(kTargetParam[t])];
      for (int rb = 0; rb < static_cast<int>(em.mean.size()); ++rb) {
        const auto d = ref.d.find({c, rb});
        if (d != ref.d.end()) em.mean[rb] += d->second;
      }
      em.conditional = ct;
    }
  }
  m.source = base.source + "; plus the object loop's conditional term on " + feature + " (" +
             (t == kDetectionTarget ? std::string("detection probability") : kObjectTargets[t]) + ")";
  return m;
}

sensor::KpiModel with_term_and_noise(const sensor::KpiModel& base, const Refit& ref, int t, const std::string& feature,
                                     int nvis, const Split& fit, const Winsor& w, std::array<bool, 3> classes) {
  sensor::KpiModel m = with_term(base, ref, t, feature, nvis, classes);
  shrink_noise_for_term(m, ref, t, feature, fit, w, nvis, classes);
  return m;
}

}  // namespace lidarsim::qualify::obj
