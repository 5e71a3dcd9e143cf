#include "qualify/residual.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "qualify/similarity.h"

namespace lidarsim::qualify {

namespace {

std::vector<double> quantile_edges(std::vector<double> x, int bins) {
  // Equal-count bins that respect ties: a value holding a large share (the ground's height, a
  // discrete feature) gets one bin and the remaining bins are spread over the rest of the data.
  std::vector<double> edges;
  if (x.empty() || bins < 2) return edges;
  std::sort(x.begin(), x.end());
  const size_t n = x.size();
  size_t i = 0;
  for (int left = bins; left > 1 && i < n; --left) {
    size_t j = i + std::max<size_t>(1, (n - i) / left);
    if (j >= n) break;
    if (x[j] <= x[i]) j = std::upper_bound(x.begin() + i, x.end(), x[i]) - x.begin();
    if (j >= n) break;
    edges.push_back(x[j]);
    i = std::lower_bound(x.begin() + i, x.end(), x[j]) - x.begin();
  }
  return edges;
}

}  // namespace

int BinnedTable::bin(double x) const {
  return static_cast<int>(std::upper_bound(edges.begin(), edges.end(), x) - edges.begin());
}

BinnedTable fit_table(const std::vector<double>& edges, const std::vector<double>& x, const std::vector<double>& r,
                      double shrink) {
  BinnedTable t;
  t.edges = edges;
  std::vector<double> sum(edges.size() + 1, 0.0);
  t.count.assign(sum.size(), 0);
  for (size_t i = 0; i < x.size(); ++i) {
    const int b = t.bin(x[i]);
    sum[b] += r[i];
    ++t.count[b];
  }
  t.value.assign(sum.size(), 0.0);
  for (size_t b = 0; b < sum.size(); ++b)
    if (t.count[b] > 0) t.value[b] = sum[b] / (t.count[b] + shrink);
  return t;
}

BinnedTable fit_binned_mean(const std::vector<double>& x, const std::vector<double>& r, int bins, double shrink) {
  return fit_table(quantile_edges(x, bins), x, r, shrink);
}

BinnedTable fit_binned_gain(const std::vector<double>& x, const std::vector<double>& measured,
                            const std::vector<double>& base, int bins, double shrink) {
  BinnedTable t;
  t.edges = quantile_edges(x, bins);
  std::vector<double> xy(t.edges.size() + 1, 0.0), xx = xy;
  t.count.assign(xy.size(), 0);
  for (size_t i = 0; i < x.size(); ++i) {
    const int b = t.bin(x[i]);
    xy[b] += measured[i] * base[i];
    xx[b] += base[i] * base[i];
    ++t.count[b];
  }
  t.value.assign(xy.size(), 1.0);
  for (size_t b = 0; b < xy.size(); ++b) {
    if (t.count[b] == 0 || xx[b] <= 0) continue;
    // Shrink towards a gain of 1 in thin bins (shrink pseudo-cells of mean base^2 at gain 1).
    const double prior = shrink * xx[b] / t.count[b];
    t.value[b] = (xy[b] + prior) / (xx[b] + prior);
  }
  return t;
}

Winsor winsor_limits(const std::vector<double>& r, double q) {
  Winsor w;
  if (r.size() < 10) return w;
  // The two order statistics a full sort would put at these places, without the sort (the
  // intensity loop takes them a few hundred times per run, on every pooled cell).
  std::vector<double> s = r;
  const size_t lo = static_cast<size_t>(q * (s.size() - 1)), hi = static_cast<size_t>((1 - q) * (s.size() - 1));
  std::nth_element(s.begin(), s.begin() + lo, s.end());
  w.lo = s[lo];
  if (hi > lo) std::nth_element(s.begin() + lo + 1, s.begin() + hi, s.end());
  if (hi < lo) std::nth_element(s.begin(), s.begin() + hi, s.begin() + lo);
  w.hi = s[hi];
  return w;
}

double mean_of(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0 : s / v.size();
}

double held_out_r2(const BinnedTable& t, const std::vector<double>& x, const std::vector<double>& r, double fit_mean) {
  double sse = 0, sst = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    const double d = r[i] - t(x[i]);
    sse += d * d;
    sst += (r[i] - fit_mean) * (r[i] - fit_mean);
  }
  return sst > 0 ? 1 - sse / sst : 0;
}

std::array<double, 2> held_out_r2_interval(const BinnedTable& t, const std::vector<double>& x,
                                           const std::vector<double>& r, double fit_mean,
                                           const std::vector<long>& block, int replicates) {
  std::map<long, std::array<double, 3>> sums;  // block -> (sse, sst, unused)
  for (size_t i = 0; i < x.size(); ++i) {
    const double d = r[i] - t(x[i]), e = r[i] - fit_mean;
    auto& s = sums[block[i]];
    s[0] += d * d, s[1] += e * e;
  }
  BlockSums b;
  for (const auto& [k, v] : sums) b.push_back(v);
  return block_bootstrap_interval(b, r2_of_sums, replicates);
}

double r2_of_sums(const std::array<double, 3>& s) { return s[1] > 0 ? 1 - s[0] / s[1] : 0; }

std::array<double, 2> block_bootstrap_interval(const BlockSums& blocks,
                                               double (*stat)(const std::array<double, 3>& sums), int replicates,
                                               std::uint64_t seed) {
  if (blocks.empty()) return {0, 0};
  std::array<double, 3> all{0, 0, 0};
  for (const auto& v : blocks)
    for (size_t k = 0; k < 3; ++k) all[k] += v[k];
  const double point = stat(all);
  SplitMix rng(seed);
  std::vector<double> reps;
  for (int k = 0; k < replicates; ++k) {
    std::array<double, 3> s{0, 0, 0};
    for (size_t j = 0; j < blocks.size(); ++j) {
      const auto& v = blocks[rng.next() % blocks.size()];
      for (size_t m = 0; m < 3; ++m) s[m] += v[m];
    }
    reps.push_back(stat(s));
  }
  std::sort(reps.begin(), reps.end());
  const auto q = [&](double p) { return reps[static_cast<size_t>(p * (reps.size() - 1))]; };
  return {2 * point - q(0.975), 2 * point - q(0.025)};
}

}  // namespace lidarsim::qualify
