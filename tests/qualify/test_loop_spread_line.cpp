// The spread_line form (qualify/objects/object_spread_forms.h): an error's sigma linear in a
// feature, with the level of each group of the model's cells refitted with it. The model holds a
// sigma per class x range bin, which averages a sigma growing with speed over a class's parked and
// moving objects; a scale per speed bin pooled over classes (spread_table) cannot give parked cars
// and walking pedestrians their own levels, the line's refitted levels can. On range the same form
// carries the growth left inside the model's 10 m bins.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <vector>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_spread_forms.h"

using namespace lidarsim;
using namespace lidarsim::qualify;

namespace {

// Objects of two classes (group = class), half of each standing: class 0 else at 5-15 m/s,
// class 1 at 0-2 m/s. True sigma s_c (1 + g speed / 10); the model's sigma is each group's RMS true sigma
// (what fit_effect's cell sd measures), u2 the squared error in its units.
struct LineSample {
  std::vector<double> x, u2, truth, model;  // truth, model: sigmas
  std::vector<int> group;
};

LineSample speed_sample(int n, double g, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> z(0, 1);
  LineSample s;
  std::vector<double> ss(2, 0.0), nn(2, 0.0);
  for (int i = 0; i < n; ++i) {
    const int c = i % 2;
    const double v = u(rng) < 0.5 ? 0.0 : c == 0 ? 5 + 10 * u(rng) : 2 * u(rng);
    s.x.push_back(v), s.group.push_back(c);
    s.truth.push_back((c == 0 ? 0.3 : 0.15) * (1 + g * v / 10));
    ss[c] += s.truth.back() * s.truth.back(), nn[c] += 1;
  }
  for (int i = 0; i < n; ++i) {
    s.model.push_back(std::sqrt(ss[s.group[i]] / nn[s.group[i]]));
    s.u2.push_back(std::pow(s.truth[i] * z(rng) / s.model[i], 2));
  }
  return s;
}

// RMS over the sample of log(predicted / true sigma), predicted = model x level x scale.
double truth_error(const LineSample& s, const BinnedTable& scale, const std::vector<double>& level) {
  double acc = 0;
  for (size_t i = 0; i < s.x.size(); ++i)
    acc += std::pow(std::log(s.model[i] * level[s.group[i]] * scale(s.x[i]) / s.truth[i]), 2);
  return std::sqrt(acc / s.x.size());
}

}  // namespace

TEST(ObjectLoopSpreadLine, GivesEachClassItsLevelForASigmaGrowingWithSpeed) {
  const LineSample fit = speed_sample(6000, 2.5, 1), held = speed_sample(6000, 2.5, 2);
  const obj::ScaleLine line = obj::fit_scale_line(fit.x, fit.u2, fit.group, 2);
  // The spread_table's scale: 10 equal-count bins of speed pooled over the classes.
  std::vector<double> v = fit.u2;
  for (double& a : v) a -= 1;
  BinnedTable table = fit_binned_mean(fit.x, v, 10);
  for (double& a : table.value) a = std::sqrt(std::max(a + 1, 0.01));
  const double before = truth_error(held, BinnedTable{{}, {1.0}, {0}}, {1.0, 1.0});
  const double with_table = truth_error(held, table, {1.0, 1.0}), with_line = truth_error(held, line.scale, line.level);
  std::cout << "  held-out RMS log(predicted / true sigma): model " << before << ", table " << with_table
            << ", line " << with_line << " (ratio " << line.ratio << ")\n";
  // The true ratio from the 1 % to the 99 % quantile of speed (0 to about 14.8 m/s) is about 4.7.
  EXPECT_GT(line.ratio, 3.5);
  EXPECT_LT(line.ratio, 6.0);
  EXPECT_LT(with_line, 0.3 * before);
  EXPECT_LT(with_line, 0.5 * with_table);
}

TEST(ObjectLoopSpreadLine, CarriesTheGrowthLeftInsideTheModelsRangeBins) {
  // Range 3-50 m, the model's sigma per 10 m bin (the group), true sigma 1 + 3 range / 40.
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> r(3, 50);
  std::normal_distribution<double> z(0, 1);
  LineSample s;
  std::vector<double> ss(5, 0.0), nn(5, 0.0);
  for (int i = 0; i < 8000; ++i) {
    s.x.push_back(r(rng)), s.group.push_back(static_cast<int>(s.x.back() / 10));
    s.truth.push_back(1 + 3 * s.x.back() / 40);
    ss[s.group.back()] += s.truth.back() * s.truth.back(), nn[s.group.back()] += 1;
  }
  for (size_t i = 0; i < s.x.size(); ++i) {
    s.model.push_back(std::sqrt(ss[s.group[i]] / nn[s.group[i]]));
    s.u2.push_back(std::pow(s.truth[i] * z(rng) / s.model[i], 2));
  }
  const obj::ScaleLine line = obj::fit_scale_line(s.x, s.u2, s.group, 5);
  const double before = truth_error(s, BinnedTable{{}, {1.0}, {0}}, std::vector<double>(5, 1.0));
  const double after = truth_error(s, line.scale, line.level);
  std::cout << "  RMS log(predicted / true sigma): model's bins " << before << ", line " << after << "\n";
  EXPECT_GT(line.ratio, 2.5);  // true: (1 + 3 x 49.5 / 40) / (1 + 3 x 3.5 / 40) = 3.7
  EXPECT_LT(after, 0.5 * before);
}

// No growth: the ratio about 1 and every level about 1, so the form is the model.
TEST(ObjectLoopSpreadLine, FindsNoGrowthWhereTheSigmaIsConstant) {
  const LineSample fit = speed_sample(6000, 0.0, 3);
  const obj::ScaleLine line = obj::fit_scale_line(fit.x, fit.u2, fit.group, 2);
  EXPECT_NEAR(line.ratio, 1.0, 0.1);
  for (double l : line.level) EXPECT_NEAR(l, 1.0, 0.05);
}
