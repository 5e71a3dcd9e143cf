// The guarded split cannot leak, the old interleaved one does (data/split.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "common/error.h"
#include "data/baselines.h"
#include "data/split.h"

using namespace lidarsim;

namespace {

int leak_circular_distance(int a, int b, int n) {
  const int d = std::abs(a - b) % n;
  return std::min(d, n - d);
}

}  // namespace

TEST(GuardedSplit, NoInputColumnIsSeenByATrainingAndAScoredCell) {
  for (const int half : {2, 9, 23, 51, 107}) {
    const auto split = data::guarded_split(half, 1024);
    const auto roles = split.roles(1024);
    long train = 0, val = 0;
    for (int t = 0; t < 1024; ++t) {
      if (roles[t] != data::kTrain) continue;
      ++train;
      for (int v = 0; v < 1024; ++v) {
        if (roles[v] != data::kValidation) continue;
        // Receptive fields [t - h, t + h] and [v - h, v + h] share no column.
        ASSERT_GT(leak_circular_distance(t, v, 1024), 2 * half) << "half-width " << half << ", columns " << t << ", " << v;
      }
    }
    val = std::count(roles.begin(), roles.end(), data::kValidation);
    EXPECT_EQ(val, 256) << half;                  // a quarter of the circle is scored
    EXPECT_GE(train, 256) << half;                // and at least a quarter trains
    EXPECT_EQ(split.regions.size(), half <= 51 ? 2u : 1u) << half;
  }
  EXPECT_THROW(data::guarded_split(200, 1024), Error);  // the guard would leave too little to train on
}

TEST(GuardedSplit, SpecsNameTheOldSplitAndFrameHoldOut) {
  EXPECT_EQ(data::parse_split("interleaved", 51).validation, (std::vector<int>{3, 7, 11, 15}));
  EXPECT_EQ(data::parse_split("guarded", 51).guard_columns, 102);
  EXPECT_EQ(data::parse_split("guarded:107", 51).guard_columns, 214);
  const auto frames = data::parse_split("frames:000003,000007", 51);
  EXPECT_EQ(frames.roles(8, "kitti/000007")[0], data::kValidation);
  EXPECT_EQ(frames.roles(8, "kitti/000017")[3], data::kTrain);
  EXPECT_THROW(data::parse_split("sectors", 51), Error);
  EXPECT_THROW(data::parse_split("guarded:x", 51), Error);
}

// Target depends on the scenery only: 16 scenery regions of 64 columns (phase 32: each old
// validation sector is half of two regions that reach into training sectors), each with its own
// class (the "scenery") and an intensity drawn independently of everything the model sees.
// The class lookup memorises scenery, as a network does: on the old split it predicts every
// validation cell exactly, though nothing about an unseen region is predictable; on the guarded
// split (guard 102 >= region width) no region is on both sides, and the error is the honest one.
TEST(GuardedSplit, SceneryOnlyTargetLeaksOnTheOldSplitNotOnTheGuardedOne) {
  data::Dataset d;
  d.channels = {"range", "class"};
  d.layout = pgm::BeamLayout::uniform(4, 2.0, -2.0, 1024);
  const int frames = 3, rows = 4, cols = 1024;
  d.pgm.resize({frames, 2, rows, cols});
  d.target.resize({frames, 1, rows, cols});
  d.mask.resize({frames, 1, rows, cols});
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.1f, 0.7f);
  std::vector<float> region_intensity(16);
  for (auto& t : region_intensity) t = u(rng);
  auto region = [](int c) { return ((c + 32) / 64) % 16; };
  for (int n = 0; n < frames; ++n) {
    d.frames.push_back("synthetic/" + std::to_string(n));
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        d.pgm.at(n, 0, r, c) = 10.f;
        d.pgm.at(n, 1, r, c) = static_cast<float>(region(c));
        d.target.at(n, 0, r, c) = region_intensity[region(c)];
        d.mask.at(n, 0, r, c) = 1.f;
      }
  }
  const auto old_split = data::evaluate_baselines(d, data::reference_split());
  const auto guarded = data::guarded_split(51, cols);
  const auto honest = data::evaluate_baselines(d, guarded);
  // The honest error: an unseen region's class falls back to the global training mean.
  const auto roles = guarded.roles(cols);
  double sum = 0, err = 0;
  long n_train = 0, n_val = 0;
  for (int c = 0; c < cols; ++c)
    if (roles[c] == data::kTrain) sum += region_intensity[region(c)], ++n_train;
  for (int c = 0; c < cols; ++c)
    if (roles[c] == data::kValidation) err += std::abs(region_intensity[region(c)] - sum / n_train), ++n_val;
  const double expected = err / n_val;
  ASSERT_GT(expected, 0.08);
  EXPECT_LT(old_split[1].validation.mae, 1e-6);  // class mean: the leak predicts perfectly
  EXPECT_NEAR(honest[1].validation.mae, expected, 1e-5);
  EXPECT_NEAR(honest[1].validation.mae, honest[0].validation.mae, 1e-5);  // no better than the global mean
}
