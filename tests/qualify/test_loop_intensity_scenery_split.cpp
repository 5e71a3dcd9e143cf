// The azimuth cross-fit on scans of one scenery (intensity_scenery.cpp) and what it judges.
//
// 1. Each class in each row block is fitted on the OTHER classes in the other row block. A split
//    into two fixed class groups leaves azimuths where only one group's classes are seen (one side
//    of a single scan: grass and trees; the other: road and buildings), so a window there had no
//    cells of the opposite group and could not be judged, though other classes were there.
// 2. Height, like azimuth, is fixed by the scenery in the columns: a window of azimuth over a hill
//    shows up in the hill's heights when height is cross-fitted over columns. On one scenery its
//    score is the lower of the column and the crossed split's, so it does not stand in for azimuth.
// Hand-built fold and pool: no scan, well under a second.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "common/angles.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/windows.h"

// A named namespace: the using-directives below must not reach the other test files of a unity
// batch (intensity_detail::Candidate would make their obj::Candidate ambiguous).
namespace scenery_split_test {

using namespace lidarsim;
using namespace lidarsim::qualify;
using namespace lidarsim::qualify::intensity_detail;
using intensity_detail::Candidate;  // over an obj::Candidate another file of the batch declares globally
using intensity_detail::Fold;

namespace {

size_t split_index_of(const std::string& name) {
  return std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), name) - kIntensityFeatures.begin();
}

struct SplitScene {
  std::vector<intensity_detail::Fold> folds;
  Pooled pool;
  std::vector<double> truth;  // noise-free intensity per pooled cell
};

struct SplitCellDraw {
  int cls = 1, row = 0;
  double deg = 0, height = 0, truth = 0;
};

// One fold holding out every other pair of cells, the pool of its held-out cells with the plain
// lookup (class x range bin over the fit cells) as base, noise sigma 0.01, one range bin.
template <class Draw>
SplitScene split_build(int cells, Draw draw) {
  const size_t iaz = split_index_of("azimuth"), ih = split_index_of("height");
  std::mt19937_64 rng(11);
  std::normal_distribution<double> noise(0, 0.01);
  SplitScene s;
  intensity_detail::Fold f;
  IntensityCells& c = f.cells;
  c.feature.assign(kIntensityFeatures.size(), {});
  std::vector<double> truth;
  for (int i = 0; i < cells; ++i) {
    const SplitCellDraw d = draw(rng, i);
    c.measured.push_back(d.truth + noise(rng));
    c.cls.push_back(d.cls), c.row.push_back(d.row);
    c.frame.push_back(0), c.sector.push_back(0), c.region.push_back(0), c.cell.push_back(i);
    c.held_out.push_back(i % 4 < 2 ? 1 : 0);
    for (size_t k = 0; k < kIntensityFeatures.size(); ++k) c.feature[k].push_back(0.0);
    c.feature[0].back() = 12.0;
    c.feature[iaz].back() = d.deg * kDeg;
    c.feature[ih].back() = d.height;
    truth.push_back(d.truth);
  }
  const std::vector<double> plain = lookup_prediction(c);
  Pooled& p = s.pool;
  p.feature.assign(kIntensityFeatures.size(), {});
  p.offset = {0};
  for (size_t i = 0; i < c.size(); ++i) {
    if (!c.held_out[i]) continue;
    f.held.push_back(i);
    p.measured.push_back(c.measured[i]), p.lookup.push_back(plain[i]), p.base.push_back(plain[i]);
    for (size_t k = 0; k < kIntensityFeatures.size(); ++k) p.feature[k].push_back(c.feature[k][i]);
    p.fold.push_back(0), p.frame.push_back(0), p.row.push_back(c.row[i]), p.cls.push_back(c.cls[i]);
    p.block.push_back(static_cast<long>(c.feature[iaz][i] / kDeg / 5));  // 5 deg strips
    // Column groups, as the rotated folds of one scan: quarters of the circle.
    p.group.push_back(std::min(3, static_cast<int>(c.feature[iaz][i] / kDeg / 90)));
    s.truth.push_back(truth[i]);
  }
  p.offset.push_back(p.size());
  p.groups = 4, p.group_by = "fold";
  s.folds.push_back(std::move(f));
  return s;
}

double split_rms_against(const std::vector<double>& pred, const std::vector<double>& truth) {
  double sq = 0;
  for (size_t i = 0; i < pred.size(); ++i) sq += (pred[i] - truth[i]) * (pred[i] - truth[i]);
  return std::sqrt(sq / pred.size());
}

}  // namespace

// Classes 1 (40 %) and 4 (10 %) on one half of the circle, 2 (30 %) and 3 (20 %) on the other:
// two class groups of about equal size are {1, 4} and {2, 3}, each on one half only. A gain of 2
// over 30-90 deg.
TEST(LoopIntensityScenerySplit, WindowWhereOneClassGroupIsSeenIsJudgedAgainstTheOtherClasses) {
  SplitScene s = split_build(40000, [](std::mt19937_64& rng, int) {
    std::uniform_real_distribution<double> u(0, 1);
    const double albedo[5] = {0, 0.5, 0.25, 0.45, 0.3};
    SplitCellDraw d;
    const double r = u(rng);
    d.cls = r < 0.4 ? 1 : r < 0.7 ? 2 : r < 0.9 ? 3 : 4;
    const bool first_half = d.cls == 1 || d.cls == 4;
    d.deg = (first_half ? 0 : 180) + 180 * u(rng);
    d.row = u(rng) < 0.5 ? 5 : 40;
    d.truth = albedo[d.cls] * (d.deg >= 30 && d.deg < 90 ? 2.0 : 1.0);
    return d;
  });
  Pooled& p = s.pool;
  scenery_cross_fit(p, "1 scan");
  ASSERT_EQ(p.azimuth_undecided, "") << "the window's classes 1 and 4 are fitted on each other";
  ASSERT_TRUE(p.azimuth_scenery.crossed);
  const size_t iaz = split_index_of("azimuth");
  const auto edges = equal_count_edges(p.feature[iaz], 16), fine = equal_count_edges(p.feature[iaz], 32);
  const double plain = split_rms_against(p.lookup, s.truth);
  const double after = split_rms_against(lookup_with_azimuth_gain(s.folds, p, Form::WindowGain, edges, fine), s.truth);
  std::printf("  error against the truth: plain lookup %.4f, window gain across classes x row blocks %.4f\n", plain, after);
  EXPECT_GT(plain, 0.05);
  EXPECT_LT(after, 0.3 * plain);
}

// A gain of 1.8 over 60-150 deg (two column groups) on every class, where the ground rises: the
// heights inside the window (2-3 m) are found nowhere else. Cross-fitted over the column groups,
// height's table carries the window from one group to the other; across classes x row blocks the
// rows' heights do not overlap inside the window, and it carries nothing.
TEST(LoopIntensityScenerySplit, HeightDoesNotStandInForAWindowOfAzimuthOnOneScenery) {
  SplitScene s = split_build(40000, [](std::mt19937_64& rng, int i) {
    std::uniform_real_distribution<double> u(0, 1);
    const double albedo[4] = {0, 0.5, 0.25, 0.4};
    SplitCellDraw d;
    d.cls = 1 + i % 3;
    d.deg = 360 * u(rng);
    const bool upper = u(rng) < 0.5;
    d.row = upper ? 5 : 40;
    const bool in = d.deg >= 60 && d.deg < 150;
    d.height = (in ? 2.0 : 0.0) + (upper ? 0.5 : 0.0) + 0.5 * u(rng);
    d.truth = albedo[d.cls] * (in ? 1.8 : 1.0);
    return d;
  });
  Pooled& p = s.pool;
  scenery_cross_fit(p, "1 scan");
  ASSERT_TRUE(p.azimuth_scenery.crossed);
  const size_t ih = split_index_of("height");
  std::vector<double> rc(p.size());
  for (size_t i = 0; i < p.size(); ++i) rc[i] = p.measured[i] - p.base[i];
  const auto edges = equal_count_edges(p.feature[ih], 16), fine = equal_count_edges(p.feature[ih], 32);
  Candidate k;
  k.feature = "height", k.form = Form::Table;
  k.score = score_form(Form::Table, p, ih, edges, fine, rc);
  const double columns = k.score.r2;
  check_across_scenery(k, p, ih, edges, fine, rc);
  std::printf("  height's additive table: held-out R^2 %.3f over column groups, %.3f after the check\n", columns, k.score.r2);
  EXPECT_GT(columns, 0.3);  // what made height the top feature
  EXPECT_TRUE(k.scenery_checked);
  EXPECT_DOUBLE_EQ(k.column_r2, columns);
  EXPECT_LT(k.score.r2, IntensityLoopOptions{}.threshold);
  // Any other feature is left as scored.
  Candidate other;
  other.feature = "incidence_angle", other.score.r2 = 0.4;
  check_across_scenery(other, p, split_index_of("incidence_angle"), edges, fine, rc);
  EXPECT_FALSE(other.scenery_checked);
  EXPECT_DOUBLE_EQ(other.score.r2, 0.4);
}

// A real effect of height, common to the classes and rows at the heights they share, passes the
// crossed split: the check refutes what only the columns carry, not every effect of height.
TEST(LoopIntensityScenerySplit, AnEffectOfHeightSharedAcrossClassesAndRowsPassesTheCheck) {
  SplitScene s = split_build(40000, [](std::mt19937_64& rng, int i) {
    std::uniform_real_distribution<double> u(0, 1);
    const double albedo[4] = {0, 0.5, 0.25, 0.4};
    SplitCellDraw d;
    d.cls = 1 + i % 3;
    d.deg = 360 * u(rng);
    d.row = u(rng) < 0.5 ? 5 : 40;
    d.height = 3 * u(rng);
    d.truth = albedo[d.cls] * (1 + 0.3 * d.height);
    return d;
  });
  Pooled& p = s.pool;
  scenery_cross_fit(p, "1 scan");
  ASSERT_TRUE(p.azimuth_scenery.crossed);
  const size_t ih = split_index_of("height");
  std::vector<double> rc(p.size());
  for (size_t i = 0; i < p.size(); ++i) rc[i] = p.measured[i] - p.base[i];
  const auto edges = equal_count_edges(p.feature[ih], 16), fine = equal_count_edges(p.feature[ih], 32);
  Candidate k;
  k.feature = "height", k.form = Form::GainTable;
  k.score = score_form(Form::GainTable, p, ih, edges, fine, rc);
  check_across_scenery(k, p, ih, edges, fine, rc);
  std::printf("  height's gain table: held-out R^2 %.3f over column groups, %.3f checked\n", k.column_r2, k.score.r2);
  EXPECT_TRUE(k.scenery_checked);
  EXPECT_GT(k.score.r2, 0.5);
}

// score_form fits the tables (additive, gain, affine) from the pooled arrays with each cell's bin
// found once (a fast variant); fit_form fits them through the shared kernels (fit_table,
// fit_gain_table) on copied cells. Both must give the same table bit for bit: the loop's JSON
// must not change with the speed-up.
TEST(LoopIntensityScenerySplit, TablesFittedFromTheBinsAreTheSharedKernelsBitForBit) {
  SplitScene s = split_build(4000, [](std::mt19937_64& rng, int i) {
    std::uniform_real_distribution<double> u(0, 1);
    SplitCellDraw d;
    d.cls = 1 + i % 3, d.deg = 360 * u(rng), d.row = u(rng) < 0.5 ? 5 : 40;
    d.height = 3 * u(rng), d.truth = 0.2 + 0.3 * u(rng);
    return d;
  });
  const Pooled& p = s.pool;
  const size_t ih = split_index_of("height");
  std::vector<double> rc(p.size());
  for (size_t i = 0; i < p.size(); ++i) rc[i] = p.measured[i] - p.base[i];
  const auto edges = equal_count_edges(p.feature[ih], 16), fine = equal_count_edges(p.feature[ih], 32);
  std::vector<size_t> all(p.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = i;
  for (Form form : {Form::Table, Form::GainTable, Form::AffineTable}) {
    const FittedForm fast = score_form(form, p, ih, edges, fine, rc).shown;
    const FittedForm plain = fit_form(form, edges, fine, p.feature[ih], rc, p.base, p.feature[0], all);
    EXPECT_EQ(fast.table.edges, plain.table.edges) << form_name(form, false);
    EXPECT_EQ(fast.table.value, plain.table.value) << form_name(form, false);
    EXPECT_EQ(fast.table.count, plain.table.count) << form_name(form, false);
    EXPECT_EQ(fast.slope, plain.slope) << form_name(form, false);
    EXPECT_EQ(fast.centre, plain.centre) << form_name(form, false);
  }
}

}  // namespace scenery_split_test
