#include "qualify/objects/object_spread_forms.h"

#include <algorithm>
#include <cmath>

#include "qualify/objects/object_terms.h"

namespace lidarsim::qualify::obj {

namespace {

// The profile negative log-likelihood of u2 ~ (level x g)^2 chi2_1 at the given g (levels at their
// maximum), up to a constant: sum over groups of n log level^2 + sum of 2 log g; the levels out.
double profile_nll(const std::vector<double>& g, const std::vector<double>& u2, const std::vector<int>& group,
                   int groups, std::vector<double>* level) {
  std::vector<double> s(groups, 0.0), n(groups, 0.0);
  double nll = 0;
  for (size_t i = 0; i < g.size(); ++i) s[group[i]] += u2[i] / (g[i] * g[i]), n[group[i]] += 1, nll += 2 * std::log(g[i]);
  if (level) level->assign(groups, 1.0);
  for (int k = 0; k < groups; ++k) {
    if (n[k] <= 0) continue;
    const double l2 = std::max(s[k] / n[k], 1e-18);
    nll += n[k] * std::log(l2);
    if (level) (*level)[k] = std::sqrt(l2);
  }
  return nll;
}

}  // namespace

ScaleLine fit_scale_line(const std::vector<double>& x, const std::vector<double>& u2, const std::vector<int>& group,
                         int groups) {
  ScaleLine out;
  const size_t n = x.size();
  out.level.assign(std::max(groups, 0), 1.0);
  out.scale.value = {1.0};
  out.scale.count = {static_cast<long>(n)};
  if (n < 2 || groups <= 0) return out;
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const double q1 = sorted[n / 100], q99 = sorted[n - 1 - n / 100], span = q99 - q1;
  if (!(span > 0)) return out;
  std::vector<double> t(n), g(n);  // t: x's position in [q1, q99] as a share of the span
  for (size_t i = 0; i < n; ++i) t[i] = (std::clamp(x[i], q1, q99) - q1) / span;
  auto nll_at = [&](double log_ratio, std::vector<double>* level) {
    const double rho = std::exp(log_ratio);
    for (size_t i = 0; i < n; ++i) g[i] = 1 + (rho - 1) * t[i];
    return profile_nll(g, u2, group, groups, level);
  };
  // A coarse grid, then golden-section search around its best point (the profile need not be
  // convex in log rho far from its minimum).
  constexpr int kGrid = 50;
  double best = 0, best_nll = nll_at(0, nullptr);
  for (int k = 0; k <= kGrid; ++k) {
    const double lr = -kMaxLogRatio + 2 * kMaxLogRatio * k / kGrid, v = nll_at(lr, nullptr);
    if (v < best_nll) best_nll = v, best = lr;
  }
  const double step = 2 * kMaxLogRatio / kGrid, phi = 0.5 * (std::sqrt(5.0) - 1);
  double a = std::max(-kMaxLogRatio, best - step), b = std::min(kMaxLogRatio, best + step);
  for (int it = 0; it < 40; ++it) {
    const double m1 = b - phi * (b - a), m2 = a + phi * (b - a);
    if (nll_at(m1, nullptr) < nll_at(m2, nullptr)) b = m2;
    else a = m1;
  }
  const double lr = 0.5 * (a + b);
  nll_at(lr, &out.level);
  out.ratio = std::exp(lr);
  const double h = span / kLineBins;
  out.scale.edges.clear(), out.scale.value.clear();
  for (int k = 1; k < kLineBins; ++k) out.scale.edges.push_back(q1 + k * h);
  for (int k = 0; k < kLineBins; ++k) out.scale.value.push_back(1 + (out.ratio - 1) * (k + 0.5) / kLineBins);
  out.scale.count.assign(kLineBins, 0);
  for (double v : x) ++out.scale.count[out.scale.bin(v)];
  return out;
}

int best_form_of_picked(const std::vector<Candidate>& cands, int picked, double threshold) {
  if (picked < 0 || picked >= static_cast<int>(cands.size())) return picked;
  const Candidate& p = cands[picked];
  int best = picked;
  for (size_t i = 0; i < cands.size(); ++i) {
    const Candidate& c = cands[i];
    if (!is_spread(c.kind) || c.feature != p.feature || c.target != p.target || c.fold_set != p.fold_set ||
        used_by_model(c))
      continue;
    if (c.score >= threshold && c.interval[0] > 0 && c.score > cands[best].score) best = static_cast<int>(i);
  }
  return best;
}

}  // namespace lidarsim::qualify::obj
