#pragma once
// Residual analysis shared by both domains: how much of a residual one candidate feature
// explains, measured honestly on data the fit never saw.
//   - BinnedTable: the residual's mean per bin of the feature (equal-count bins on the fit split
//     that respect ties, so a heavily repeated value gets its own bin), shrunk towards 0 in thin bins;
//   - held_out_r2: 1 - SSE(residual - table) / SSE(residual - fit mean) on the held-out split,
//     i.e. the share of the held-out residual variance (beyond a constant) the table explains.
//     Negative when the table only fits noise of the fit split.
// Residuals are winsorised at the fit split's 1st/99th percentile for fitting and scoring, so a
// handful of gross errors (heavy tails) cannot decide the ranking alone.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace lidarsim::qualify {

struct BinnedTable {
  std::vector<double> edges;  // ascending cut points; bin k = values in [edges[k-1], edges[k])
  std::vector<double> value;  // edges.size() + 1 bins
  std::vector<long> count;
  int bin(double x) const;
  double operator()(double x) const { return value[bin(x)]; }
};

// Mean of r per bin of the given edges, shrunk by n / (n + shrink).
BinnedTable fit_table(const std::vector<double>& edges, const std::vector<double>& x, const std::vector<double>& r,
                      double shrink = 5);
// Up to `bins` equal-count bins of x (ties kept together), mean of r per bin shrunk by n / (n + shrink).
BinnedTable fit_binned_mean(const std::vector<double>& x, const std::vector<double>& r, int bins = 10,
                            double shrink = 5);
// Multiplicative variant for intensity: per bin the least-squares gain g with measured ~ g * base.
BinnedTable fit_binned_gain(const std::vector<double>& x, const std::vector<double>& measured,
                            const std::vector<double>& base, int bins = 10, double shrink = 5);

struct Winsor {
  double lo = -1e300, hi = 1e300;
  double operator()(double v) const { return v < lo ? lo : v > hi ? hi : v; }
};
Winsor winsor_limits(const std::vector<double>& r, double q = 0.01);

double mean_of(const std::vector<double>& v);
double held_out_r2(const BinnedTable& t, const std::vector<double>& x, const std::vector<double>& r, double fit_mean);
// held_out_r2 from sums (sse, sst, -) of squared deviations from the table and from the fit mean.
double r2_of_sums(const std::array<double, 3>& sums);
// Basic-bootstrap 95% interval of held_out_r2 over blocks of held-out cells (block[i] = the
// block of cell i, e.g. scan x sector): neighbouring cells are not independent, blocks nearly are.
std::array<double, 2> held_out_r2_interval(const BinnedTable& t, const std::vector<double>& x,
                                           const std::vector<double>& r, double fit_mean,
                                           const std::vector<long>& block, int replicates = 1000);

// Sums of one block of held-out samples, for a statistic of whole-split sums (an R^2, an RMS).
using BlockSums = std::vector<std::array<double, 3>>;

// Basic-bootstrap 95% interval (2 stat - q97.5, 2 stat - q2.5) of stat(sums over blocks),
// resampling whole blocks with a fixed seed: samples of one block (a scan sector, a track) are not
// independent, blocks nearly are. {0, 0} without blocks.
std::array<double, 2> block_bootstrap_interval(const BlockSums& blocks,
                                               double (*stat)(const std::array<double, 3>& sums),
                                               int replicates = 1000, std::uint64_t seed = 11);

struct FeatureScore {
  std::string feature;
  double score = 0;     // held-out share of residual variance explained
  std::string target;   // which residual it explains best (objects: the parameter)
  std::array<double, 2> interval{0, 0};  // the score's 95% interval, where computed
};

}  // namespace lidarsim::qualify
