// The interleaved split leaks for a network too, the guarded one does not (data/split.h): a
// tiny UNet on a target that depends on the scenery only. 16 scenery regions of 16 columns (phase
// 8: every interleaved validation sector is half of two regions that reach into training sectors), each
// seen through its own one-hot input channel, each with an intensity drawn independently of
// everything. On the interleaved split the network predicts the held-out cells from the same scenery on
// the training side; on the guarded split (guard 2 x 9 columns >= a region) it cannot, and its
// error is that of the honest guess or worse (measured: 0.041 interleaved, 0.294 guarded, guess 0.234).
#include <gtest/gtest.h>

#include <random>

#include "data/baselines.h"
#include "data/split.h"
#include "nn/receptive_field.h"
#include "train/trainer.h"

using namespace lidarsim;

namespace {

data::Dataset scenery_only(std::vector<float>& intensity) {
  const int frames = 3, rows = 2, cols = 256, regions = 16;
  data::Dataset d;
  for (int k = 0; k < regions; ++k) d.channels.push_back("r" + std::to_string(k));
  d.channels.push_back("range");
  d.channels.push_back("class");  // one class: the baselines need it
  d.layout = pgm::BeamLayout::uniform(rows, 1.0, -1.0, cols);
  d.pgm.resize({frames, regions + 2, rows, cols});
  d.target.resize({frames, 1, rows, cols});
  d.mask.resize({frames, 1, rows, cols});
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.1f, 0.7f);
  intensity.resize(regions);
  for (auto& t : intensity) t = u(rng);
  for (int n = 0; n < frames; ++n) {
    d.frames.push_back("synthetic/" + std::to_string(n));
    d.row_modes.push_back("firing_order");
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        const int region = ((c + 8) / 16) % regions;
        d.pgm.at(n, region, r, c) = 1.f;
        d.pgm.at(n, regions, r, c) = 10.f;
        d.target.at(n, 0, r, c) = intensity[region];
        d.mask.at(n, 0, r, c) = 1.f;
      }
  }
  return d;
}

double validation_mae(const data::Dataset& d, const std::string& split) {
  train::TrainConfig c;
  c.encoder.channels.clear();
  for (int k = 0; k < 16; ++k) c.encoder.channels.push_back("r" + std::to_string(k));
  c.base = 4, c.depth = 1;  // receptive-field half-width 9 columns
  c.epochs = 1, c.steps_per_epoch = 400, c.batch = 2, c.lr = 1e-2f;
  c.augment_roll = c.augment_mirror = false;
  c.threads = 1, c.out.clear(), c.progress = false, c.split = split;
  return train::train_on(c, {&d}, {"synthetic"}).epochs.back().validation.mae;
}

}  // namespace

TEST(SplitLeak, TinyUnetOnSceneryOnlyTargetLeaksOnTheOldSplitNotOnTheGuardedOne) {
  ASSERT_EQ(nn::receptive_field_half_width({16, 1, 4, 1}), 9);
  std::vector<float> intensity;
  const data::Dataset d = scenery_only(intensity);
  const double leaked = validation_mae(d, "interleaved"), honest = validation_mae(d, "guarded");
  // The honest guess for an unseen region: the training mean, scored on the guarded cells.
  const double guess = data::evaluate_baselines(d, data::guarded_split(9, 256))[0].validation.mae;
  std::printf("old split %.4f, guarded %.4f, global-mean guess on the guarded cells %.4f\n", leaked, honest, guess);
  EXPECT_LT(leaked, 0.3 * honest);
  EXPECT_GT(honest, 0.7 * guess);
}
