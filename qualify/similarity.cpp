#include "qualify/similarity.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

#include "common/error.h"

namespace lidarsim::qualify {

namespace {

double percentile_sorted(const std::vector<double>& s, double q) {
  if (s.empty()) return 0;
  const double x = q * (s.size() - 1);
  const size_t k = std::min(static_cast<size_t>(x), s.size() - 1);
  const size_t k1 = std::min(k + 1, s.size() - 1);
  return s[k] + (x - k) * (s[k1] - s[k]);
}

std::vector<double> sorted(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v;
}

}  // namespace

std::uint64_t SplitMix::next() {
  std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

double SplitMix::uniform() { return (next() >> 11) * 0x1.0p-53; }

double SplitMix::normal() {
  const double u1 = std::max(uniform(), 1e-300), u2 = uniform();
  return std::sqrt(-2 * std::log(u1)) * std::cos(2 * std::numbers::pi * u2);
}

int SharedBins::index(double x) const {
  if (x < lo) return 0;
  if (x >= hi) return bins + 1;
  const double w = (hi - lo) / bins;
  return 1 + std::min(bins - 1, static_cast<int>((x - lo) / w));
}

SharedBins shared_bins(const std::vector<double>& a, const std::vector<double>& b, int bins) {
  std::vector<double> pooled = a;
  pooled.insert(pooled.end(), b.begin(), b.end());
  std::sort(pooled.begin(), pooled.end());
  SharedBins s;
  s.bins = std::max(1, bins);
  s.lo = percentile_sorted(pooled, 0.01);
  s.hi = percentile_sorted(pooled, 0.99);
  // A degenerate spread (e.g. all values equal) still gets a bin of unit width around it.
  if (!(s.hi > s.lo)) s.lo -= 0.5, s.hi += 0.5;
  // hi is exclusive: nudge it so the 99th percentile itself falls inside.
  s.hi = std::nextafter(s.hi, s.hi + 1);
  return s;
}

std::vector<double> histogram(const std::vector<double>& v, const SharedBins& bins) {
  std::vector<double> h(bins.bins + 2, 0.0);
  if (v.empty()) return h;
  for (double x : v) h[bins.index(x)] += 1.0;
  for (double& x : h) x /= v.size();
  return h;
}

double histogram_intersection(const std::vector<double>& a, const std::vector<double>& b, int bins) {
  if (a.empty() || b.empty()) return 0;
  const SharedBins sb = shared_bins(a, b, bins);
  const auto p = histogram(a, sb), q = histogram(b, sb);
  double s = 0;
  for (size_t k = 0; k < p.size(); ++k) s += std::min(p[k], q[k]);
  return std::min(1.0, s);
}

double ks_statistic(const std::vector<double>& a_in, const std::vector<double>& b_in) {
  if (a_in.empty() || b_in.empty()) return 1;
  const auto a = sorted(a_in), b = sorted(b_in);
  size_t i = 0, j = 0;
  double d = 0;
  while (i < a.size() && j < b.size()) {
    const double x = std::min(a[i], b[j]);
    while (i < a.size() && a[i] <= x) ++i;
    while (j < b.size() && b[j] <= x) ++j;
    d = std::max(d, std::abs(double(i) / a.size() - double(j) / b.size()));
  }
  return d;
}

double wasserstein1(const std::vector<double>& a_in, const std::vector<double>& b_in) {
  if (a_in.empty() || b_in.empty()) return 0;
  const auto a = sorted(a_in), b = sorted(b_in);
  // Integral of |F_a - F_b| over the merged support.
  size_t i = 0, j = 0;
  double x = std::min(a[0], b[0]), w = 0;
  while (i < a.size() || j < b.size()) {
    const double next = j >= b.size() || (i < a.size() && a[i] <= b[j]) ? a[i] : b[j];
    w += std::abs(double(i) / a.size() - double(j) / b.size()) * (next - x);
    x = next;
    while (i < a.size() && a[i] <= x) ++i;
    while (j < b.size() && b[j] <= x) ++j;
  }
  return w;
}

Interval bootstrap_intersection(const std::vector<double>& a, const std::vector<double>& b, int bins, int reps,
                                std::uint64_t seed) {
  if (a.empty() || b.empty() || reps < 2) return {};
  SplitMix rng(seed);
  std::vector<double> ra(a.size()), rb(b.size()), values;
  values.reserve(reps);
  for (int r = 0; r < reps; ++r) {
    for (double& x : ra) x = a[rng.next() % a.size()];
    for (double& x : rb) x = b[rng.next() % b.size()];
    values.push_back(histogram_intersection(ra, rb, bins));
  }
  std::sort(values.begin(), values.end());
  // Basic (reverse-percentile) interval: resampling adds noise that lowers the intersection, so
  // the plain percentile interval would sit below the estimate; reflecting around it corrects that.
  const double est = histogram_intersection(a, b, bins);
  return {std::clamp(2 * est - percentile_sorted(values, 0.975), 0.0, 1.0),
          std::clamp(2 * est - percentile_sorted(values, 0.025), 0.0, 1.0)};
}

PairedDifference paired_group_difference(const std::vector<double>& a, const std::vector<long>& group_a,
                                         const std::vector<double>& b, const std::vector<long>& group_b,
                                         const std::vector<double>& m, const std::vector<long>& group_m, int bins,
                                         int reps, std::uint64_t seed) {
  if (a.size() != group_a.size() || b.size() != group_b.size() || m.size() != group_m.size())
    throw Error("paired_group_difference: a sample and its groups differ in length");
  PairedDifference d;
  d.a = histogram_intersection(a, m, bins);
  d.b = histogram_intersection(b, m, bins);
  d.interval = {d.a - d.b, d.a - d.b};
  std::map<long, int> id;  // m's groups -> 0..G-1
  for (long g : group_m) id.try_emplace(g, static_cast<int>(id.size()));
  const int G = static_cast<int>(id.size());
  d.groups = G;
  if (G < 2 || a.empty() || b.empty() || reps < 2) return d;
  // Per group, counts over the bins of (a, m) and of (b, m): a resample is then a weighted sum.
  const SharedBins ba = shared_bins(a, m, bins), bb = shared_bins(b, m, bins);
  const int cells = bins + 2;
  auto counts = [&](const std::vector<double>& v, const std::vector<long>& g, const SharedBins& sb) {
    std::vector<double> c(static_cast<size_t>(G) * cells, 0.0);
    for (size_t i = 0; i < v.size(); ++i) {
      const auto it = id.find(g[i]);
      if (it != id.end()) c[static_cast<size_t>(it->second) * cells + sb.index(v[i])] += 1;
    }
    return c;
  };
  const auto ca = counts(a, group_a, ba), cma = counts(m, group_m, ba), cb = counts(b, group_b, bb),
             cmb = counts(m, group_m, bb);
  auto intersection = [&](const std::vector<double>& sim, const std::vector<double>& meas, const std::vector<int>& w) {
    std::vector<double> p(cells, 0.0), q(cells, 0.0);
    for (int g = 0; g < G; ++g)
      if (w[g])
        for (int k = 0; k < cells; ++k)
          p[k] += w[g] * sim[static_cast<size_t>(g) * cells + k], q[k] += w[g] * meas[static_cast<size_t>(g) * cells + k];
    double sp = 0, sq = 0, s = 0;
    for (int k = 0; k < cells; ++k) sp += p[k], sq += q[k];
    if (sp <= 0 || sq <= 0) return 0.0;
    for (int k = 0; k < cells; ++k) s += std::min(p[k] / sp, q[k] / sq);
    return std::min(1.0, s);
  };
  SplitMix rng(seed);
  std::vector<int> w(G);
  std::vector<double> values;
  values.reserve(reps);
  for (int r = 0; r < reps; ++r) {
    std::fill(w.begin(), w.end(), 0);
    for (int k = 0; k < G; ++k) ++w[rng.next() % static_cast<std::uint64_t>(G)];
    values.push_back(intersection(ca, cma, w) - intersection(cb, cmb, w));
  }
  std::sort(values.begin(), values.end());
  // Basic interval from the resamples' deviations around the unresampled draw (every group once;
  // it differs from the point estimate only by the samples of groups m does not hold).
  std::fill(w.begin(), w.end(), 1);
  const double centre = intersection(ca, cma, w) - intersection(cb, cmb, w), est = d.a - d.b;
  d.interval = {est - (percentile_sorted(values, 0.975) - centre), est - (percentile_sorted(values, 0.025) - centre)};
  return d;
}

Similarity compare(const std::vector<double>& sim, const std::vector<double>& real, int bins, int reps,
                   std::uint64_t seed) {
  Similarity s;
  s.n_a = static_cast<long>(sim.size());
  s.n_b = static_cast<long>(real.size());
  s.intersection = histogram_intersection(sim, real, bins);
  s.interval = bootstrap_intersection(sim, real, bins, reps, seed);
  s.ks = ks_statistic(sim, real);
  s.wasserstein = wasserstein1(sim, real);
  return s;
}

double real_vs_real_ceiling(const std::vector<std::vector<double>>& groups, int bins) {
  std::vector<double> h[2];
  for (size_t g = 0; g < groups.size(); ++g) h[g % 2].insert(h[g % 2].end(), groups[g].begin(), groups[g].end());
  if (h[0].empty() || h[1].empty()) return -1;
  return histogram_intersection(h[0], h[1], bins);
}

}  // namespace lidarsim::qualify
