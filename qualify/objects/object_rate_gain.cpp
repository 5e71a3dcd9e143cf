#include "qualify/objects/object_rate_gain.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>

#include "qualify/residual.h"
#include "sensor/kpi_fit.h"

namespace lidarsim::qualify::obj {

namespace {

// Fit records aggregated by class, cell and fine bin of x: what the joint fit needs of them.
struct Group {
  int cls = 0, cell = 0, bin = 0;
  double n = 0, hits = 0;
};

// The base model's detection rule (sensor/kpi_fit.cpp shrunk_detection_rates) per class with each
// group's trials counted at its bin's gain g[bin]: q[class][cell].
PerClass<std::vector<double>> cells_at_gain(const std::vector<Group>& groups, const std::vector<double>& g, int nrange,
                                            int nvis) {
  const double k = sensor::kDetectionPriorObjects;
  const int ncells = nrange * nvis;
  PerClass<std::vector<double>> trials, hits, q;
  for (int c = 0; c < kObjectClassCount; ++c) trials[c].assign(ncells, 0.0), hits[c].assign(ncells, 0.0);
  for (const Group& G : groups) trials[G.cls][G.cell] += G.n * g[G.bin], hits[G.cls][G.cell] += G.hits;
  for (int c = 0; c < kObjectClassCount; ++c) {
    double all_trials = 0, all_hits = 0;
    for (int j = 0; j < ncells; ++j) all_trials += trials[c][j], all_hits += hits[c][j];
    const double overall = all_trials > 0 ? std::clamp(all_hits / all_trials, 0.0, 1.0) : 0.0;
    q[c].assign(ncells, overall);
    for (int r = 0; r < nrange; ++r) {
      double row_trials = 0, row_hits = 0, own = 0, weight = 0;
      for (int v = 0; v < nvis; ++v) {
        const double n = trials[c][r * nvis + v], d = hits[c][r * nvis + v];
        row_trials += n, row_hits += d, own += n * d / (n + k), weight += n * k / (n + k);
      }
      const double m = row_trials >= k && weight > 0 ? std::clamp((row_hits - own) / weight, 0.0, 1.0) : overall;
      for (int v = 0; v < nvis; ++v) {
        const int j = r * nvis + v;
        q[c][j] = std::clamp((hits[c][j] + k * m) / (trials[c][j] + k), 0.0, 1.0);
      }
    }
  }
  return q;
}

struct GainFit {
  double gain = 1, loglik = -1e300;
  PerClass<std::vector<double>> q;
};

// The joint fit for the window of fine bins [a, b]: cells and gain alternately, then its log-likelihood.
GainFit fit_window_gain(const std::vector<Group>& groups, int nbins, int a, int b, int nrange, int nvis,
                        int iterations) {
  std::vector<double> g(nbins, 1.0);
  GainFit out;
  for (int it = 0; it < iterations; ++it) {
    out.q = cells_at_gain(groups, g, nrange, nvis);
    double in_hits = 0, in_expected = 0;
    for (const Group& G : groups)
      if (G.bin >= a && G.bin <= b) in_hits += G.hits, in_expected += G.n * out.q[G.cls][G.cell];
    const double last = out.gain;
    out.gain = in_expected > 0 ? std::clamp(in_hits / in_expected, 0.0, 10.0) : 1.0;
    for (int f = a; f <= b; ++f) g[f] = out.gain;
    if (it > 0 && std::abs(out.gain - last) < 1e-6) break;
  }
  out.q = cells_at_gain(groups, g, nrange, nvis);
  out.loglik = 0;
  for (const Group& G : groups) {
    const double p = std::clamp(out.q[G.cls][G.cell] * g[G.bin], 1e-3, 1 - 1e-3);
    out.loglik += G.hits * std::log(p) + (G.n - G.hits) * std::log(1 - p);
  }
  return out;
}

// The fit records aggregated by class, cell and bin of t, and the records below each bin (N[k]:
// before bin k; N[bins]: all).
struct Grouped {
  std::vector<Group> groups;
  std::vector<long> N;
};

Grouped group_records(const std::vector<double>& x, const std::vector<double>& y, const std::vector<int>& cls,
                      const std::vector<int>& cells, const BinnedTable& t) {
  const int K = static_cast<int>(t.value.size());
  std::map<std::tuple<int, int, int>, Group> by_key;
  std::vector<long> per_bin(K, 0);
  for (size_t i = 0; i < x.size(); ++i) {
    if (cls[i] < 0 || cls[i] >= kObjectClassCount) continue;
    const int f = t.bin(x[i]);
    Group& G = by_key[{cls[i], cells[i], f}];
    G.cls = cls[i], G.cell = cells[i], G.bin = f, G.n += 1, G.hits += y[i];
    ++per_bin[f];
  }
  Grouped out;
  for (const auto& [key, G] : by_key) out.groups.push_back(G);
  out.N.assign(K + 1, 0);
  for (int f = 0; f < K; ++f) out.N[f + 1] = out.N[f] + per_bin[f];
  return out;
}

// The cells q as offsets from the base's, for every cell of every class the base models and the
// groups hold.
std::map<std::pair<int, int>, double> cell_offsets(const std::vector<Group>& groups,
                                                   const PerClass<std::vector<double>>& q,
                                                   const sensor::KpiModel& base, int nvis) {
  std::map<std::pair<int, int>, double> d;
  PerClass<bool> fitted{};
  for (const Group& G : groups) fitted[G.cls] = true;
  for (int c = 0; c < kObjectClassCount; ++c) {
    const auto it = base.classes.find(kObjectClasses[c]);
    if (it == base.classes.end() || !fitted[c]) continue;
    const auto& dp = it->second.detection_probability;
    for (int r = 0; r < base.range_bins() && r < static_cast<int>(dp.size()); ++r)
      for (int v = 0; v < nvis && v < static_cast<int>(dp[r].size()); ++v)
        d[{c, r * nvis + v}] = q[c][r * nvis + v] - dp[r][v];
  }
  return d;
}

}  // namespace

PerClass<std::vector<double>> rate_gain_cells(const std::vector<double>& y, const std::vector<double>& g,
                                              const std::vector<int>& cls, const std::vector<int>& cells, int nrange,
                                              int nvis) {
  std::vector<Group> groups;
  std::vector<double> gains;
  for (size_t i = 0; i < y.size(); ++i) {
    if (cls[i] < 0 || cls[i] >= kObjectClassCount) continue;
    groups.push_back({cls[i], cells[i], static_cast<int>(gains.size()), 1.0, y[i]});
    gains.push_back(g[i]);
  }
  return cells_at_gain(groups, gains, nrange, nvis);
}

Refit fit_rate_gain(const std::vector<double>& x, const std::vector<double>& y, const std::vector<int>& cls,
                    const std::vector<int>& cells, const sensor::KpiModel& base, int nvis, int fine_bins,
                    long min_side) {
  const int nrange = base.range_bins();
  const BinnedTable fine = fit_binned_mean(x, y, fine_bins, 0);
  const int K = static_cast<int>(fine.value.size());
  const Grouped coarse = group_records(x, y, cls, cells, fine);
  const std::vector<Group>& groups = coarse.groups;
  const std::vector<long>& N = coarse.N;
  constexpr int kIterations = 6;   // alternations of cells and gain per window compared
  constexpr int kConverged = 500;  // for the window kept (stops when the gain moves < 1e-6)
  GainFit best = fit_window_gain(groups, K, 0, -1, nrange, nvis, 1);  // no window: the base's own rule
  int ba = -1, bb = -1;
  // Each edge costs the log of the records: the BIC of a change point (Yao 1988), whose location is
  // searched over and so costs twice a regular parameter's half log (whether there is a gain at
  // all is for the held-out judgement). The cells on either side of a dropout's edge learn its rate
  // themselves where the fit split holds them, so beyond a range the likelihood is nearly flat in a
  // window's far edge: a far edge placed where the rate merely drifts (the mix of visibility
  // beyond the edge) buys a few units of log-likelihood by chance, and with it the rows the fit
  // split barely holds lose the gain (beyond 30 m a held-out class at its undropped rate, 0.67
  // where the truth was 0.02). With half the log per edge, a dropout beyond 21.6 m was fitted as a
  // window to 30 m on one fold; the full log keeps the step.
  const double cost = std::log(std::max<double>(2.0, static_cast<double>(N[K])));
  double best_penalised = best.loglik;
  for (int a = 0; a < K; ++a)
    for (int b = a; b < K; ++b) {
      if (a == 0 && b == K - 1) continue;
      const long in = N[b + 1] - N[a];
      if (in < min_side || N[K] - in < min_side) continue;
      GainFit f = fit_window_gain(groups, K, a, b, nrange, nvis, kIterations);
      const double penalised = f.loglik - cost * ((a > 0) + (b < K - 1));
      if (penalised > best_penalised) best_penalised = penalised, best = std::move(f), ba = a, bb = b;
    }
  Refit out;
  out.table.pooled.value = {0.0};
  out.table.pooled.count = {N[K]};
  BinnedTable& w = out.gain.pooled;
  if (ba < 0) {
    w.value = {1.0}, w.count = {N[K]};
  } else {
    // Each edge refined on a grid kRefine times finer, within one coarse bin of where it was
    // found (the other edge kept): an equal-count coarse bin of range spans 1-3 m, and an edge
    // left a bin off the dropout's puts the objects between them on the wrong side, which also
    // biases the gain fitted against the row they share (a dropout beyond 20.8 m found at 22.1 m
    // with gain 0.27 where it was 0.05). Same number of edges, so the likelihood alone decides.
    constexpr int kRefine = 4;
    const BinnedTable finer = fit_binned_mean(x, y, kRefine * fine_bins, 0);
    const int K4 = static_cast<int>(finer.value.size());
    const Grouped F = group_records(x, y, cls, cells, finer);
    int a4 = ba > 0 ? finer.bin(fine.edges[ba - 1]) : 0, b4 = bb < K - 1 ? finer.bin(fine.edges[bb]) - 1 : K4 - 1;
    best = fit_window_gain(F.groups, K4, a4, b4, nrange, nvis, kIterations);
    auto try_window = [&](int a, int b) {
      const long in = F.N[b + 1] - F.N[a];
      if (a > b || in < min_side || F.N[K4] - in < min_side) return;
      GainFit f = fit_window_gain(F.groups, K4, a, b, nrange, nvis, kIterations);
      if (f.loglik > best.loglik) best = std::move(f), a4 = a, b4 = b;
    };
    if (ba > 0)
      for (int a = std::max(1, a4 - kRefine), a_at = a4; a <= a_at + kRefine; ++a) try_window(a, b4);
    if (bb < K - 1)
      for (int b = b4 - kRefine, b_at = b4; b <= std::min(K4 - 2, b_at + kRefine); ++b) try_window(a4, b);
    // The alternation converges slowly where rows lie wholly inside the window (their cells take
    // whatever the gain leaves: g moves by a share of the step each pass), so the window kept is
    // fitted to convergence; the choice above compares windows at kIterations passes each.
    best = fit_window_gain(F.groups, K4, a4, b4, nrange, nvis, kConverged);
    if (a4 > 0) w.edges.push_back(finer.edges[a4 - 1]), w.value.push_back(1.0), w.count.push_back(F.N[a4]);
    w.value.push_back(best.gain), w.count.push_back(F.N[b4 + 1] - F.N[a4]);
    if (b4 < K4 - 1)
      w.edges.push_back(finer.edges[b4]), w.value.push_back(1.0), w.count.push_back(F.N[K4] - F.N[b4 + 1]);
  }
  out.d = cell_offsets(groups, best.q, base, nvis);
  return out;
}

}  // namespace lidarsim::qualify::obj
