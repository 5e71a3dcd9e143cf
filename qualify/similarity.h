#pragma once
// Similarity of two samples of one KPI (simulated vs measured, or measured vs measured):
//   - histogram intersection = 1 - total variation, on bins shared by both samples (equal bins
//     over the 1st-99th percentile of the pooled samples plus one overflow bin at each end), with
//     a bootstrap 95% interval (both samples resampled, fixed seed);
//   - two-sample Kolmogorov-Smirnov statistic (largest gap between the empirical CDFs);
//   - 1-D Wasserstein distance (area between the empirical CDFs), in the KPI's unit.
// And the real-vs-real ceiling: the same intersection between two disjoint halves of the
// measured data, split by group (sequence, track, scan sector) so the halves are not correlated.
// Finite samples of one distribution do not reach 1, so a similarity is judged against it.
#include <cstdint>
#include <vector>

namespace lidarsim::qualify {

inline constexpr int kDefaultBins = 40;

// Shared bin edges for a and b: `bins` equal bins over the pooled 1st-99th percentile.
struct SharedBins {
  double lo = 0, hi = 1;
  int bins = kDefaultBins;
  int index(double x) const;  // 0 = below lo, 1..bins inside, bins + 1 = at or above hi
};
SharedBins shared_bins(const std::vector<double>& a, const std::vector<double>& b, int bins = kDefaultBins);
// Normalised histogram (sums to 1) over bins + 2 cells.
std::vector<double> histogram(const std::vector<double>& v, const SharedBins& bins);

// sum_k min(p_k, q_k) in [0, 1]; 0 when either sample is empty.
double histogram_intersection(const std::vector<double>& a, const std::vector<double>& b, int bins = kDefaultBins);
double ks_statistic(const std::vector<double>& a, const std::vector<double>& b);
double wasserstein1(const std::vector<double>& a, const std::vector<double>& b);

struct Interval {
  double lo = 0, hi = 0;
};
// Basic bootstrap 95% interval (2 est - q97.5, 2 est - q2.5) of the intersection; `reps` resamples, fixed `seed`.
// It is an interval for the intersection of the two distributions, not of the samples: sampling
// noise lowers an intersection on average, so the resamples sit below the estimate and the basic
// interval corrects that bias upward, so with few samples it can lie wholly above the estimate.
Interval bootstrap_intersection(const std::vector<double>& a, const std::vector<double>& b, int bins = kDefaultBins,
                                int reps = 200, std::uint64_t seed = 1);

// Which of two simulations, a or b, is closer to the measured sample m, with the uncertainty that
// m holds a finite set of groups (tracks, scans): each sample carries its group. The point
// estimates are histogram_intersection(a, m) and (b, m), each on its own shared bins as there. The
// interval is a basic bootstrap 95% interval of their difference over m's groups drawn with
// replacement, a draw taking the group's measured samples and both simulations' samples for it
// together (bins kept from the full samples); samples of groups m does not hold are dropped from
// the resamples. An interval wholly above 0: a is closer on this data; one that spans 0: the
// data cannot tell them apart. Fewer than two groups: the interval is the point difference.
struct PairedDifference {
  double a = 0, b = 0;  // intersections of a and of b with m
  Interval interval;    // of a - b
  long groups = 0;
  double difference() const { return a - b; }
};
PairedDifference paired_group_difference(const std::vector<double>& a, const std::vector<long>& group_a,
                                         const std::vector<double>& b, const std::vector<long>& group_b,
                                         const std::vector<double>& m, const std::vector<long>& group_m,
                                         int bins = kDefaultBins, int reps = 1000, std::uint64_t seed = 1);

struct Similarity {
  long n_a = 0, n_b = 0;
  double intersection = 0;
  Interval interval;
  double ks = 0, wasserstein = 0;
  double ceiling = -1;  // real-vs-real, -1 when not computed
};
Similarity compare(const std::vector<double>& sim, const std::vector<double>& real, int bins = kDefaultBins,
                   int reps = 200, std::uint64_t seed = 1);

// Real-vs-real ceiling: groups alternate between two halves (0, 2, 4, ... vs 1, 3, 5, ...),
// each half pooled; the intersection of the two halves. Needs two non-empty halves, else -1.
double real_vs_real_ceiling(const std::vector<std::vector<double>>& groups, int bins = kDefaultBins);

// Small deterministic RNG (splitmix64) for bootstrap and synthetic data.
struct SplitMix {
  std::uint64_t state;
  explicit SplitMix(std::uint64_t seed) : state(seed) {}
  std::uint64_t next();
  double uniform();  // [0, 1)
  double normal();   // N(0, 1), Box-Muller
};

}  // namespace lidarsim::qualify
