// Similarity measures on cases worked out by hand, and the residual table/R^2 they rank with.
#include <gtest/gtest.h>

#include <vector>

#include "common/error.h"
#include "qualify/residual.h"
#include "qualify/similarity.h"

using namespace lidarsim::qualify;

TEST(Similarity, IdenticalSamplesIntersectFully) {
  const std::vector<double> a = {0.1, 0.5, 0.7, 2.0, 3.5};
  EXPECT_NEAR(histogram_intersection(a, a), 1.0, 1e-12);
}

TEST(Similarity, DisjointSamplesDoNotIntersect) {
  EXPECT_NEAR(histogram_intersection({0, 0.1, 0.2}, {100, 101, 102}), 0.0, 1e-12);
}

TEST(Similarity, HalfTheMassSharedGivesOneHalf) {
  // a: half at 0, half at 1; b: all at 0 -> min(0.5, 1) + min(0.5, 0) = 0.5.
  EXPECT_NEAR(histogram_intersection({0, 0, 1, 1}, {0, 0, 0, 0}), 0.5, 1e-12);
}

TEST(Similarity, IntersectionIsSymmetricOnSharedBins) {
  const std::vector<double> a = {0, 1, 2, 3, 4, 5}, b = {2, 2.5, 3, 9};
  EXPECT_NEAR(histogram_intersection(a, b), histogram_intersection(b, a), 1e-12);
}

TEST(Similarity, KsIsTheLargestCdfGap) {
  // F_a - F_b at x = 1: 1/3 - 0; at 2: 2/3 - 1/3; at 3: 1 - 2/3.
  EXPECT_NEAR(ks_statistic({1, 2, 3}, {2, 3, 4}), 1.0 / 3, 1e-12);
  EXPECT_NEAR(ks_statistic({0, 0}, {5, 6}), 1.0, 1e-12);
  EXPECT_NEAR(ks_statistic({1, 2}, {2, 1}), 0.0, 1e-12);
}

TEST(Similarity, WassersteinIsTheShiftForShiftedSamples) {
  EXPECT_NEAR(wasserstein1({0, 1}, {1, 2}), 1.0, 1e-12);
  EXPECT_NEAR(wasserstein1({0}, {3}), 3.0, 1e-12);
  // {0, 2} vs {1}: |F_a - F_b| = 1/2 on [0, 1) and 1/2 on [1, 2) -> 1.
  EXPECT_NEAR(wasserstein1({0, 2}, {1}), 1.0, 1e-12);
}

TEST(Similarity, CeilingOfOneDistributionSplitByGroupIsNearOneAndOfTwoIsLow) {
  SplitMix rng(3);
  std::vector<std::vector<double>> same(4), diff(4);
  for (int g = 0; g < 4; ++g)
    for (int i = 0; i < 5000; ++i) {
      same[g].push_back(rng.normal());
      diff[g].push_back(rng.normal() + (g % 2 ? 10 : 0));
    }
  EXPECT_GT(real_vs_real_ceiling(same), 0.9);  // 20000 samples, 42 bins: sampling noise ~0.03
  EXPECT_LT(real_vs_real_ceiling(diff), 0.05);
  EXPECT_EQ(real_vs_real_ceiling({{1, 2, 3}}), -1);  // one group: no second half
}

TEST(Similarity, BootstrapIntervalIsReproducibleAndBracketsTheEstimate) {
  SplitMix rng(5);
  std::vector<double> a, b;
  for (int i = 0; i < 2000; ++i) a.push_back(rng.normal()), b.push_back(rng.normal() * 1.3);
  const Interval i1 = bootstrap_intersection(a, b, 40, 200, 11), i2 = bootstrap_intersection(a, b, 40, 200, 11);
  EXPECT_EQ(i1.lo, i2.lo);
  EXPECT_EQ(i1.hi, i2.hi);
  const double est = histogram_intersection(a, b);
  EXPECT_LE(i1.lo, est);
  EXPECT_GE(i1.hi, est);
  EXPECT_LT(i1.hi - i1.lo, 0.1);
}

namespace {
// Values with their group (track) ids.
struct Grouped {
  std::vector<double> v;
  std::vector<long> g;
};
// Measured-style data: `groups` groups of `per` samples, each group offset by its own
// N(0, spread) draw plus N(0, 0.3) noise, shifted by `shift`; appended to `out`.
void add_groups(SplitMix& rng, int groups, int per, double spread, double shift, Grouped& out) {
  for (int k = 0; k < groups; ++k) {
    const double offset = spread * rng.normal();
    for (int i = 0; i < per; ++i) out.v.push_back(shift + offset + 0.3 * rng.normal()), out.g.push_back(k);
  }
}
Grouped measured(SplitMix& rng, int groups, int per, double spread) {
  Grouped m;
  add_groups(rng, groups, per, spread, 0, m);
  return m;
}
// A simulation for the same groups: `seeds` fresh draws of every group (ids 0..groups-1).
Grouped simulated(SplitMix& rng, int groups, int per, int seeds, double spread, double shift) {
  Grouped s;
  for (int q = 0; q < seeds; ++q) add_groups(rng, groups, per, spread, shift, s);
  return s;
}
PairedDifference paired(const Grouped& a, const Grouped& b, const Grouped& m) {
  return paired_group_difference(a.v, a.g, b.v, b.g, m.v, m.g);
}
}  // namespace

TEST(Similarity, PairedGroupDifferenceKeepsTheIntersectionsAsPointEstimates) {
  SplitMix rng(21);
  const Grouped m = measured(rng, 20, 30, 0.5);
  const Grouped a = simulated(rng, 20, 30, 8, 0.5, 0);
  const Grouped b = simulated(rng, 20, 30, 8, 0.5, 0.4);
  const PairedDifference d = paired(a, b, m);
  EXPECT_DOUBLE_EQ(d.a, histogram_intersection(a.v, m.v));
  EXPECT_DOUBLE_EQ(d.b, histogram_intersection(b.v, m.v));
  EXPECT_EQ(d.groups, 20);
  const PairedDifference again = paired(a, b, m);
  EXPECT_EQ(d.interval.lo, again.interval.lo);  // fixed seed: reproducible
  EXPECT_EQ(d.interval.hi, again.interval.hi);
  const std::vector<long> short_ids(a.g.begin(), a.g.end() - 1);
  EXPECT_THROW(paired_group_difference(a.v, short_ids, b.v, b.g, m.v, m.g), lidarsim::Error);
}

TEST(Similarity, PairedGroupDifferenceIsSureOfAShiftAndNotOfTwoDrawsOfOneModel) {
  SplitMix rng(22);
  const Grouped m = measured(rng, 40, 25, 0.5);
  const Grouped right = simulated(rng, 40, 25, 16, 0.5, 0);
  const Grouped again = simulated(rng, 40, 25, 16, 0.5, 0);
  const Grouped shifted = simulated(rng, 40, 25, 16, 0.5, 0.6);
  const PairedDifference sure = paired(right, shifted, m);
  EXPECT_GT(sure.interval.lo, 0) << sure.difference();
  const PairedDifference same = paired(right, again, m);
  EXPECT_LT(same.interval.lo, 0);
  EXPECT_GT(same.interval.hi, 0);
}

TEST(Similarity, PairedGroupDifferenceResamplesWholeGroups) {
  // The same measured values, once labelled by their 6 real groups and once each its own group:
  // with lumpy groups the group bootstrap must be the wider (fewer independent draws).
  SplitMix rng(23);
  const Grouped m = measured(rng, 6, 80, 0.8);
  const Grouped a = simulated(rng, 6, 80, 16, 0.8, 0);
  const Grouped b = simulated(rng, 6, 80, 16, 0.8, 0.3);
  // Each sample its own group; simulated samples follow the measured sample at the same place in
  // their group's block.
  Grouped own_m = m, own_a = a, own_b = b;
  for (size_t i = 0; i < m.v.size(); ++i) own_m.g[i] = static_cast<long>(i);
  for (size_t i = 0; i < a.v.size(); ++i) own_a.g[i] = static_cast<long>(i % m.v.size());
  for (size_t i = 0; i < b.v.size(); ++i) own_b.g[i] = static_cast<long>(i % m.v.size());
  const PairedDifference by_group = paired(a, b, m);
  const PairedDifference by_sample = paired(own_a, own_b, own_m);
  EXPECT_DOUBLE_EQ(by_group.difference(), by_sample.difference());
  EXPECT_GT(by_group.interval.hi - by_group.interval.lo, 1.5 * (by_sample.interval.hi - by_sample.interval.lo));
}

TEST(Residual, BinnedTableRecoversAStepAndScoresItOnHeldOutData) {
  std::vector<double> x, r;
  for (int i = 0; i < 100; ++i) x.push_back(i), r.push_back(i < 50 ? -1 : 1);  // cut lands at 50
  const BinnedTable t = fit_binned_mean(x, r, 2, 0);
  ASSERT_EQ(t.value.size(), 2u);
  EXPECT_NEAR(t(10), -1, 1e-12);
  EXPECT_NEAR(t(90), 1, 1e-12);
  EXPECT_NEAR(held_out_r2(t, {5, 95}, {-1, 1}, 0.0), 1.0, 1e-12);
  // A feature unrelated to the residual explains nothing (R^2 <= 0 on the held-out points).
  EXPECT_LE(held_out_r2(t, {5, 95}, {1, -1}, 0.0), 0.0);
}

TEST(Residual, BlockBootstrapIntervalOfTheScoreExcludesZeroForARealStepAndNotForNoise) {
  // 40 blocks of 50 cells: a step of +-0.5 under unit noise (R^2 ~ 0.2), and noise alone.
  SplitMix rng(5);
  std::vector<double> x, step, noise;
  std::vector<long> block;
  for (int b = 0; b < 40; ++b)
    for (int i = 0; i < 50; ++i) {
      const double xi = rng.uniform(), e = rng.normal();
      x.push_back(xi), block.push_back(b);
      step.push_back((xi < 0.5 ? -0.5 : 0.5) + e), noise.push_back(e);
    }
  BinnedTable t;
  t.edges = {0.5};
  t.value = {-0.5, 0.5};
  t.count = {1, 1};
  const double s = held_out_r2(t, x, step, 0.0);
  const auto ci = held_out_r2_interval(t, x, step, 0.0, block);
  EXPECT_GT(ci[0], 0.1);
  EXPECT_LE(ci[0], s);
  EXPECT_GE(ci[1], s);
  BinnedTable zero = t;
  zero.value = {0.01, -0.01};  // a table fitted to noise elsewhere: no signal here
  const auto cn = held_out_r2_interval(zero, x, noise, 0.0, block);
  EXPECT_LT(cn[0], 0.0);
  EXPECT_LT(cn[1], 0.01);
}

TEST(Residual, GainTableRecoversAMultiplicativeFactorPerBin) {
  std::vector<double> x, m, b;
  for (int i = 0; i < 100; ++i) x.push_back(i), b.push_back(0.5), m.push_back(i < 50 ? 0.25 : 1.0);  // cut at 50
  const BinnedTable g = fit_binned_gain(x, m, b, 2, 0);
  EXPECT_NEAR(g(0), 0.5, 1e-12);
  EXPECT_NEAR(g(99), 2.0, 1e-12);
}

TEST(Residual, TiedValuesKeepOneBinAndTheRestSpreadOverTheOthers) {
  // 80 values tied at -1.73 (the ground), 20 distinct above: the tie gets one bin, not 8 of 10.
  std::vector<double> x(80, -1.73), r(100, 0.0);
  for (int i = 0; i < 20; ++i) x.push_back(i * 0.1);
  const BinnedTable t = fit_binned_mean(x, r, 10, 0);
  EXPECT_EQ(t.bin(-1.73), 0);
  EXPECT_GE(t.value.size(), 8u);
}
