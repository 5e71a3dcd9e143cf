// The spread_growth form (qualify/objects/object_candidates.h): a sigma that grows with range within
// the KPI model's own range bins. The model holds a sigma per 10 m range bin, so what is left of a
// sigma growing with range is its growth inside each bin; equal-count bins of range (spread_table)
// straddle the model's edges and carry it poorly, a power of range over its bin's mean range does.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <vector>

#include "qualify/objects/object_candidates.h"

using namespace lidarsim;
using namespace lidarsim::qualify;

namespace {

// Squared standardised residuals of a sigma 1 + g range / 40 about the model's per-bin sigma (the
// RMS of the true sigma over each 10 m bin), as fit_effect hands them to the scale fit.
struct Sample {
  std::vector<double> x, u2;
  std::vector<int> cell;
};

Sample sample(int n, double g, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> range(3, 50);
  std::normal_distribution<double> z(0, 1);
  auto sigma = [g](double r) { return 1 + g * r / 40; };
  Sample s;
  for (int i = 0; i < n; ++i) s.x.push_back(range(rng)), s.cell.push_back(static_cast<int>(s.x.back() / 10));
  std::vector<double> ss(6, 0.0), nn(6, 0.0);
  for (int i = 0; i < n; ++i) ss[s.cell[i]] += std::pow(sigma(s.x[i]), 2), nn[s.cell[i]] += 1;
  for (int i = 0; i < n; ++i) {
    const double model = std::sqrt(ss[s.cell[i]] / nn[s.cell[i]]), e = sigma(s.x[i]) * z(rng);
    s.u2.push_back(std::pow(e / model, 2));
  }
  return s;
}

// Held-out Gaussian deviance per object, sum of 2 ln(scale) + u2 / scale^2, minus that at scale 1.
double deviance_gain(const BinnedTable& scale, const Sample& held) {
  double g = 0;
  for (size_t i = 0; i < held.x.size(); ++i) {
    const double s = scale(held.x[i]);
    g += held.u2[i] - (2 * std::log(s) + held.u2[i] / (s * s));
  }
  return g / held.x.size();
}

}  // namespace

TEST(ObjectLoopSpreadGrowth, CarriesASigmaGrowingWithRangeWithinTheModelsBins) {
  const Sample fit = sample(6000, 3.0, 1), held = sample(6000, 3.0, 2);
  double k = 0;
  const BinnedTable growth = obj::fit_scale_growth(fit.x, fit.u2, fit.cell, &k);
  // ln sigma's slope in ln range within a bin is g r / (40 + g r): 0.2 at 3 m, 0.8 at 50 m.
  EXPECT_GT(k, 0.3);
  EXPECT_LT(k, 1.0);
  // What the old forms had: 10 equal-count bins of range (spread_table's scale).
  std::vector<double> v = fit.u2;
  for (double& a : v) a -= 1;
  BinnedTable table = fit_binned_mean(fit.x, v, 10);
  for (double& a : table.value) a = std::sqrt(std::max(a + 1, 0.01));
  const double gain_growth = deviance_gain(growth, held), gain_table = deviance_gain(table, held);
  std::cout << "  k " << k << ", held-out deviance gain per object: growth " << gain_growth << ", table "
            << gain_table << "\n";
  // Small per object (what is left inside 10 m bins), but where the table finds nothing.
  EXPECT_GT(gain_growth, 0.004);
  EXPECT_GT(gain_growth, gain_table + 0.004);
  // Within a bin the scale rises with range and is about 1 at the bin's mean range.
  EXPECT_LT(growth(21), growth(29));
  EXPECT_NEAR(growth(25), 1.0, 0.05);
}

// No growth: k about 0 and the scale about 1 everywhere, so the form adds nothing.
TEST(ObjectLoopSpreadGrowth, FindsNoGrowthWhereTheSigmaIsConstant) {
  const Sample fit = sample(6000, 0.0, 3);
  double k = 1;
  const BinnedTable growth = obj::fit_scale_growth(fit.x, fit.u2, fit.cell, &k);
  EXPECT_NEAR(k, 0, 0.1);
  for (double x : {5.0, 15.0, 35.0, 48.0}) EXPECT_NEAR(growth(x), 1.0, 0.1) << x;
}
