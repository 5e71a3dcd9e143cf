// The loop's bias terms shrunk by their own track-bootstrap uncertainty (qualify/objects/object_terms.h
// shrink_by_track_bootstrap): a bin carried by few tracks is trusted less than the same bin value
// carried by many, a strong effect seen on many tracks survives nearly whole, noise goes. And the
// base model's per-track size constants pooled across classes (object_folds.h pool_track_spread).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <random>
#include <vector>

#include "qualify/objects/object_folds.h"
#include "qualify/objects/object_terms.h"

namespace {

using lidarsim::qualify::obj::backfit;
using lidarsim::qualify::obj::Refit;
using lidarsim::qualify::obj::shrink_by_track_bootstrap;

// Records of one class (Car) and one range cell; residual = the track's constant + frame noise.
struct Data {
  std::vector<double> x, r;
  std::vector<int> cls, rb, track;
  void add_track(double feature, double offset, int frames, std::mt19937_64& rng, double noise = 0.05) {
    std::normal_distribution<double> n(0.0, noise);
    const int id = track.empty() ? 0 : track.back() + 1;
    for (int f = 0; f < frames; ++f)
      x.push_back(feature), r.push_back(offset + n(rng)), cls.push_back(0), rb.push_back(0), track.push_back(id);
  }
};

// The same high-bin effect (+0.3 on average over its tracks, track-to-track spread 0.4) once on
// 300 tracks of one frame, once on 3 tracks of 100 frames; the low bin holds 300 tracks around 0.
Data two_bins(bool few_tracks) {
  std::mt19937_64 rng(3);
  Data d;
  const double pattern[3] = {-1, 0, 1};
  for (int j = 0; j < 300; ++j) d.add_track(0.0, 0.4 * pattern[j % 3], 1, rng);
  if (few_tracks)
    for (int j = 0; j < 3; ++j) d.add_track(1.0, 0.3 + 0.4 * pattern[j], 100, rng);
  else
    for (int j = 0; j < 300; ++j) d.add_track(1.0, 0.3 + 0.4 * pattern[j % 3], 1, rng);
  return d;
}

double high_bin(const Refit& f) { return f.table.per_class[0](1.0); }

TEST(TermShrink, AnEffectCarriedByThreeTracksIsShrunkMuchMoreThanOneCarriedByThreeHundred) {
  double fitted[2], kept[2];
  for (int few = 0; few < 2; ++few) {
    const Data d = two_bins(few == 1);
    Refit f = backfit(d.x, d.r, d.cls, d.rb, 2);
    ASSERT_TRUE(f.table.own[0]);
    fitted[few] = high_bin(f);
    shrink_by_track_bootstrap(f, d.x, d.r, d.cls, d.rb, d.track, false);
    kept[few] = high_bin(f);
  }
  // Same fitted effect either way (the data differ only in how many tracks carry it).
  EXPECT_NEAR(fitted[0], 0.3, 0.03);
  EXPECT_NEAR(fitted[1], 0.3, 0.03);
  const double share_many = kept[0] / fitted[0], share_few = kept[1] / fitted[1];
  std::cout << "  kept: 300 tracks " << share_many << ", 3 tracks " << share_few << "\n";
  EXPECT_GT(share_many, 0.9) << "300 tracks: the effect is well determined";
  EXPECT_LT(share_few, 0.6) << "3 tracks with a 0.4 spread between them: a standard error of ~0.19";
  EXPECT_GT(share_few, 0.0) << "but not noise either";
}

TEST(TermShrink, AStrongPlantedEffectOnManyTracksSurvivesNearlyWhole) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> n(0.0, 0.15);
  Data d;
  for (int j = 0; j < 300; ++j) {
    const double x = u(rng);
    d.add_track(x, 1.0 * (x - 0.5) + n(rng), 8, rng);
  }
  Refit f = backfit(d.x, d.r, d.cls, d.rb, 10);
  const Refit raw = f;
  shrink_by_track_bootstrap(f, d.x, d.r, d.cls, d.rb, d.track, false);
  double largest = 0;
  for (double v : raw.table.per_class[0].value) largest = std::max(largest, std::abs(v));
  ASSERT_GT(largest, 0.35);
  for (size_t b = 0; b < f.table.per_class[0].value.size(); ++b)
    EXPECT_NEAR(f.table.per_class[0].value[b], raw.table.per_class[0].value[b], 0.05 * largest) << "bin " << b;
  // The factors and standard errors are reported alongside.
  ASSERT_EQ(f.factor.per_class[0].value.size(), raw.table.per_class[0].value.size());
  for (double s : f.se.per_class[0].value) EXPECT_GT(s, 0.0);
}

TEST(TermShrink, ATableOfNoiseFromFewTracksIsShrunkTowardsZero) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> n(0.0, 0.3);
  Data d;
  for (int j = 0; j < 12; ++j) d.add_track(u(rng), n(rng), 40, rng);  // no effect of x at all
  Refit f = backfit(d.x, d.r, d.cls, d.rb, 10);
  const Refit raw = f;
  shrink_by_track_bootstrap(f, d.x, d.r, d.cls, d.rb, d.track, false);
  double before = 0, after = 0;
  for (size_t b = 0; b < raw.table.per_class[0].value.size(); ++b)
    before += std::pow(raw.table.per_class[0].value[b], 2), after += std::pow(f.table.per_class[0].value[b], 2);
  ASSERT_GT(before, 0.0);
  std::cout << "  noise table RMS kept " << std::sqrt(after / before) << "\n";
  EXPECT_LT(std::sqrt(after / before), 0.6) << "the bins are no larger than their own noise (0.63 without the floor)";
}

TEST(TermShrink, TheCellOffsetsAreRefittedSoTheMeanIsKept) {
  const Data d = two_bins(true);
  Refit f = backfit(d.x, d.r, d.cls, d.rb, 2);
  shrink_by_track_bootstrap(f, d.x, d.r, d.cls, d.rb, d.track, false);
  double fitted = 0, measured = 0;
  for (size_t i = 0; i < d.r.size(); ++i) fitted += f(d.cls[i], d.rb[i], d.x[i]), measured += d.r[i];
  EXPECT_NEAR(fitted / d.r.size(), measured / d.r.size(), 1e-9);
}

// Two classes share a slope on x (as the detectors' width prior is shared); class 0 shows it on
// 300 tracks, class 1 on 4 tracks. Towards 0, class 1's table loses much of the slope; towards the
// pooled table, it keeps the shape the other class shows.
TEST(TermShrink, AClassWithFewTracksIsPooledTowardsTheSharedShapeNotTowardsZero) {
  std::mt19937_64 rng(13);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> n(0.0, 0.2);
  Data d;
  auto add = [&](int cls, int tracks, int frames) {
    for (int j = 0; j < tracks; ++j) {
      const double x = u(rng);
      d.add_track(x, 0.8 * (x - 0.5) + n(rng), frames, rng);
      for (int f = 0; f < frames; ++f) d.cls[d.cls.size() - 1 - f] = cls;
    }
  };
  add(0, 300, 4);
  add(1, 4, 60);
  Refit zero = backfit(d.x, d.r, d.cls, d.rb, 4);
  ASSERT_TRUE(zero.table.own[0] && zero.table.own[1]);
  Refit pooled = zero;
  const Refit raw = zero;
  shrink_by_track_bootstrap(zero, d.x, d.r, d.cls, d.rb, d.track, false, false);
  shrink_by_track_bootstrap(pooled, d.x, d.r, d.cls, d.rb, d.track, false, true);
  // The class-1 table's slope: its top bin minus its bottom bin, against the truth 0.8 x spread.
  auto span = [](const Refit& f) { return f.table.per_class[1].value.back() - f.table.per_class[1].value.front(); };
  const double truth = 0.8 * 0.6;
  std::cout << "  class-1 span: raw " << span(raw) << ", towards 0 " << span(zero) << ", towards pooled "
            << span(pooled) << "\n";  // roughly the difference between the outer bins' centres
  EXPECT_LT(std::abs(span(pooled) - truth), std::abs(span(zero) - truth))
      << "raw " << span(raw) << ", towards 0 " << span(zero) << ", towards pooled " << span(pooled);
  // Class 0 (many tracks) is hardly moved either way.
  for (size_t b = 0; b < raw.table.per_class[0].value.size(); ++b)
    EXPECT_NEAR(pooled.table.per_class[0].value[b], raw.table.per_class[0].value[b], 0.03) << "bin " << b;
}

}  // namespace

// The base model's per-track size constants pooled across classes (qualify/objects/object_folds.h
// pool_track_spread): a class seen on few tracks is pulled towards the others' ratio of per-track
// to within-track spread, a class seen on many keeps its own.
namespace {

lidarsim::sensor::ErrorModel size_error(double sigma, double track_std) {
  lidarsim::sensor::ErrorModel e;
  e.sigma = {sigma, sigma};
  e.track_std = track_std;
  return e;
}

TEST(TrackSpreadPooling, AClassWithFewTracksBorrowsTheOthersRatioAClassWithManyKeepsItsOwn) {
  using lidarsim::sensor::KpiParam;
  lidarsim::sensor::KpiModel m;
  // Ratios track_std / sigma: Car 1.0 (200 tracks), Pedestrian 1.1 (200 tracks), Cyclist 2.0 (5 tracks).
  const double ratio[3] = {1.0, 1.1, 2.0};
  const int tracks[3] = {200, 200, 5};
  const char* names[3] = {"Car", "Pedestrian", "Cyclist"};
  lidarsim::qualify::ObjectSet fit;
  for (int c = 0; c < 3; ++c) {
    lidarsim::sensor::ClassModel cm;
    for (KpiParam p : {KpiParam::Length, KpiParam::Width, KpiParam::Height})
      cm.errors[int(p)] = size_error(0.1, 0.1 * ratio[c]);
    m.classes[names[c]] = cm;
    for (int t = 0; t < tracks[c]; ++t)
      for (int f = 0; f < 10; ++f) {
        lidarsim::qualify::ObjectRecord r;
        r.cls = c, r.seq = 0, r.track = 1000 * c + t, r.frame = f, r.detected = true;
        fit.records.push_back(r);
      }
  }
  const auto applied = lidarsim::qualify::obj::pool_track_spread(m, fit);
  const double cyc = m.classes.at("Cyclist").errors[int(KpiParam::Length)].track_std / 0.1;
  const double car = m.classes.at("Car").errors[int(KpiParam::Length)].track_std / 0.1;
  std::cout << "  Cyclist ratio 2.0 -> " << cyc << ", Car 1.0 -> " << car << "\n";
  EXPECT_LT(cyc, 1.6) << "5 tracks: pulled most of the way from 2.0 towards ~1.05";
  EXPECT_GT(cyc, 1.0);
  EXPECT_NEAR(car, 1.0, 0.03) << "200 tracks: its own";
  EXPECT_NEAR(applied[2][0], cyc / 2.0, 1e-9);
}

}  // namespace
