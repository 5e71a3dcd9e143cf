// The azimuth window gain judged across classes x row blocks (intensity_scenery.cpp): its window
// must be found as the joint model (levels per class x range bin refitted with the gain), not as
// the best additive window of the plain lookup's residual. The plain lookup holds the window's gain
// in proportion to each key's share of cells inside it; a class that lies mostly inside the window
// and a little elsewhere leaves its largest residual OUTSIDE the window (where its level is too
// high), and the additive search goes there. Hand-built fold and pool: no scan, milliseconds.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "common/angles.h"
#include "qualify/intensity/intensity_internal.h"
#include "qualify/windows.h"

// A named namespace: the using-directives below must not reach the other test files of a unity
// batch (intensity_detail::Candidate would make their obj::Candidate ambiguous).
namespace window_edges_test {

using namespace lidarsim;
using namespace lidarsim::qualify;
using namespace lidarsim::qualify::intensity_detail;
using intensity_detail::Candidate;  // over an obj::Candidate another file of the batch declares globally
using intensity_detail::Fold;

namespace {

struct Scene {
  std::vector<intensity_detail::Fold> folds;
  Pooled pool;
  std::vector<double> truth;  // noise-free intensity per pooled cell
};

// Four classes in two class groups, each group with a "spanning" class (90 % of its cells in the
// window [0, 60) deg, 10 % in [200, 240) deg) and a class spread over every azimuth; rows in two
// blocks at random; every other cell held out. Gain 2 inside the window, noise sigma 0.01.
Scene window_scene() {
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> noise(0, 0.01);
  const double albedo[4] = {0.5, 0.25, 0.45, 0.3};  // spanning, spread, spanning, spread
  Scene s;
  intensity_detail::Fold f;
  IntensityCells& c = f.cells;
  c.feature.assign(kIntensityFeatures.size(), {});
  std::vector<double> truth;
  for (int i = 0; i < 40000; ++i) {
    const int cls = i % 4;
    double deg;
    if (cls % 2 == 0) deg = u(rng) < 0.9 ? 60 * u(rng) : 200 + 40 * u(rng);
    else deg = 360 * u(rng);
    const double az = (deg > 180 ? deg - 360 : deg) * kDeg;
    const double t = albedo[cls] * (deg < 60 ? 2.0 : 1.0);
    c.measured.push_back(t + noise(rng));
    c.cls.push_back(cls + 1);
    c.row.push_back(u(rng) < 0.5 ? 5 : 40);
    c.frame.push_back(0), c.sector.push_back(0), c.region.push_back(0), c.cell.push_back(i);
    c.held_out.push_back(i % 8 < 4 ? 1 : 0);  // neighbours of each class in both halves
    for (size_t k = 0; k < kIntensityFeatures.size(); ++k) c.feature[k].push_back(0.0);
    c.feature[0].back() = 12.0;  // one range bin
    c.feature[iaz].back() = az;
    truth.push_back(t);
  }
  // The pool: the held-out cells, with the plain lookup (class x range bin over the fit cells).
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
    p.block.push_back(static_cast<long>(p.block.size() % 64));
    // Class groups {1, 2} and {3, 4}; row blocks at row 20.
    p.azimuth_scenery.group.push_back(2 * (c.cls[i] >= 3 ? 1 : 0) + (c.row[i] >= 20 ? 1 : 0));
    s.truth.push_back(truth[i]);
  }
  p.offset.push_back(p.size());
  p.azimuth_scenery.groups = 4, p.azimuth_scenery.crossed = true;
  s.folds.push_back(std::move(f));
  return s;
}

double rms_against(const std::vector<double>& pred, const std::vector<double>& truth) {
  double sq = 0;
  for (size_t i = 0; i < pred.size(); ++i) sq += (pred[i] - truth[i]) * (pred[i] - truth[i]);
  return std::sqrt(sq / pred.size());
}

}  // namespace

TEST(LoopIntensityWindowEdges, WindowGainIsFoundAsTheJointModelNotTheAdditiveResidualsWindow) {
  const Scene s = window_scene();
  const Pooled& p = s.pool;
  const size_t iaz = std::find(kIntensityFeatures.begin(), kIntensityFeatures.end(), "azimuth") - kIntensityFeatures.begin();
  const auto edges = equal_count_edges(p.feature[iaz], 16), fine = equal_count_edges(p.feature[iaz], 32);
  const double plain = rms_against(p.lookup, s.truth);
  const std::vector<double> joint = lookup_with_azimuth_gain(s.folds, p, Form::WindowGain, edges, fine);
  const double after = rms_against(joint, s.truth);
  std::printf("  error against the truth: plain lookup %.4f, window gain refitted jointly %.4f\n", plain, after);
  // The plain lookup is off by about a third of the albedo on the spread classes inside the window
  // and on the spanning classes outside it; the joint window removes nearly all of it (0.016,
  // 0.13 x). The additive window over the plain lookup's residual, refitted with the levels as
  // before, leaves 0.041 (0.33 x).
  EXPECT_GT(plain, 0.1);
  EXPECT_LT(after, 0.2 * plain);
  // The window's edges, fitted on every cell: within 3 deg of 0 and 60 deg.
  std::vector<size_t> all(p.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = i;
  const FittedForm w = joint_window_gain(s.folds, p, all, equal_count_edges(p.feature[iaz], kWindowFineBins));
  ASSERT_TRUE(w.ok());
  EXPECT_NEAR(w.table.edges[0] / kDeg, 0, 3);
  EXPECT_NEAR(w.table.edges[1] / kDeg, 60, 3);
  EXPECT_NEAR(w.table.value[1], 2.0, 0.15);  // 3 alternations of levels and gains: within a few %
}

}  // namespace window_edges_test
