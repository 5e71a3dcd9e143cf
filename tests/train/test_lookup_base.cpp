// The lookup base (train/lookup_fit.h, nn/unet.h lookup): fitted on training cells only, the
// model starts at exactly the lookup's prediction and learns the residual over it. Synthetic
// set: intensity = a class x range table + a per-row offset + a local effect a lookup cannot
// express (cells up to 6 columns after a pole column are brighter; the network sees the pole).
#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "data/baselines.h"
#include "data/frame_source.h"
#include "data/split.h"
#include "pgm/materials.h"
#include "train/lookup_fit.h"
#include "train/trainer.h"

using namespace lidarsim;

namespace {

constexpr int kLookupRows = 8, kLookupCols = 256, kLookupFrames = 3;

data::Dataset lookup_synthetic() {
  data::Dataset d;
  d.channels = {"range", "class"};
  d.layout = pgm::BeamLayout::uniform(kLookupRows, 1.0, -1.0, kLookupCols);
  d.pgm.resize({kLookupFrames, 2, kLookupRows, kLookupCols});
  d.target.resize({kLookupFrames, 1, kLookupRows, kLookupCols});
  d.mask.resize({kLookupFrames, 1, kLookupRows, kLookupCols});
  const int classes[3] = {pgm::cls::road, pgm::cls::building, pgm::cls::vegetation};
  for (int n = 0; n < kLookupFrames; ++n) {
    d.frames.push_back("synthetic/" + std::to_string(n));
    d.row_modes.push_back("firing_order");
    for (int r = 0; r < kLookupRows; ++r)
      for (int c = 0; c < kLookupCols; ++c) {
        const unsigned h = static_cast<unsigned>(n * 7919 + r * 131 + c * 31) * 2654435761u;
        const int k = static_cast<int>((c / 5 + r + n) % 3);
        const float range = 2.f + static_cast<float>((h >> 8) % 3000) / 100.f;  // 2..32 m
        const int phase = (c + 40 * n) % 32;
        const bool pole_near = phase >= 1 && phase <= 6;  // a local effect of the pole at phase 0
        d.pgm.at(n, 0, r, c) = range;
        d.pgm.at(n, 1, r, c) = static_cast<float>(phase == 0 ? pgm::cls::pole : classes[k]);
        d.target.at(n, 0, r, c) = 0.1f + 0.15f * k + 0.004f * range + 0.02f * (r % 4) + (pole_near ? 0.2f : 0.f);
        d.mask.at(n, 0, r, c) = (h >> 4) % 10 != 0 ? 1.f : 0.f;  // 10 % empty cells
      }
  }
  return d;
}

train::TrainConfig lookup_config() {
  train::TrainConfig c;
  c.encoder.channels = {"range", "class"};
  c.base = 4, c.depth = 1;  // receptive-field half-width 9: the guarded split fits at 256 columns
  c.epochs = 1, c.steps_per_epoch = 300, c.batch = 2, c.lr = 1e-2f;
  c.augment_roll = c.augment_mirror = false;
  c.threads = 1, c.out.clear(), c.progress = false;
  c.lookup_base = true;
  return c;
}

}  // namespace

TEST(LookupBase, FitIsTheClassRangeMeanPlusTheRowResidualOfTrainingCellsOnly) {
  data::Dataset d = lookup_synthetic();
  const data::SectorSplit split = data::guarded_split(9, kLookupCols);
  auto fit_of = [&](const data::Dataset& set) {
    const auto source = data::memory_frame_source(set, "synthetic");
    const train::TrainingFrames frames({source.get()}, lookup_config().encoder, split);
    return train::fit_lookup_base(train::lookup_base_config(lookup_config().encoder, kLookupRows), frames, kLookupCols);
  };
  const train::LookupFit fit = fit_of(d);
  // Independently: road (group "road") at 10-15 m, and the row residuals.
  const nn::LookupBaseConfig lc = train::lookup_base_config(lookup_config().encoder, kLookupRows);
  int road = -1;
  for (int g = 0; g < lc.classes; ++g)
    if (lookup_config().encoder.class_groups[g].name == "road") road = g;
  ASSERT_GE(road, 0);
  double sum = 0;
  long n = 0, cells = 0;
  for (int f = 0; f < kLookupFrames; ++f) {
    const auto roles = split.roles(kLookupCols, d.frames[f]);
    for (int r = 0; r < kLookupRows; ++r)
      for (int c = 0; c < kLookupCols; ++c) {
        if (d.mask.at(f, 0, r, c) <= 0 || roles[c] != data::kTrain) continue;
        ++cells;
        if (d.pgm.at(f, 1, r, c) == static_cast<float>(pgm::cls::road) && data::range_bin(d.pgm.at(f, 0, r, c)) == 2)
          sum += d.target.at(f, 0, r, c), ++n;
      }
  }
  ASSERT_GT(n, 10);
  EXPECT_EQ(fit.cells, cells);
  EXPECT_NEAR(fit.table[road * lc.range_bins + 2], sum / n, 1e-5);
  // The rows differ by 0.02 steps (r % 4): the fitted offsets follow.
  EXPECT_NEAR(fit.beam[3] - fit.beam[0], 0.06, 0.02);
  // Leak-free: what the validation and guard columns hold does not change the fit.
  for (int f = 0; f < kLookupFrames; ++f) {
    const auto roles = split.roles(kLookupCols, d.frames[f]);
    for (int r = 0; r < kLookupRows; ++r)
      for (int c = 0; c < kLookupCols; ++c)
        if (roles[c] != data::kTrain) d.target.at(f, 0, r, c) = 5.f;
  }
  const train::LookupFit again = fit_of(d);
  EXPECT_EQ(again.table, fit.table);
  EXPECT_EQ(again.beam, fit.beam);
}

TEST(LookupBase, TrainingStartsAtTheLookupAndLearnsTheLocalEffectBeyondIt) {
  const data::Dataset d = lookup_synthetic();
  const train::TrainResult r = train::train_on(lookup_config(), {&d}, {"synthetic"});
  ASSERT_TRUE(r.lookup_validation.has_value());
  const double lookup = r.lookup_validation->mae, after = r.epochs.back().validation.mae;
  // The table alone equals the class x range lookup scored the same way (groups = classes here;
  // the per-row offsets make it better).
  const auto baselines = data::evaluate_baselines(d, data::guarded_split(9, kLookupCols));
  std::printf("class x range %.4f, lookup base alone %.4f, after training %.4f\n", baselines[2].validation.mae,
              lookup, after);
  EXPECT_LT(lookup, baselines[2].validation.mae + 1e-3);
  EXPECT_GT(lookup, 0.05);  // the local effect is left to the network
  EXPECT_LT(after, 0.6 * lookup);
  // The checkpointed settings carry the lookup base.
  EXPECT_GT(r.model->config().lookup.classes, 0);
}
