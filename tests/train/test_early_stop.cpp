// Early stopping that cannot leak (train/early_stop.h, TrainConfig::early_stop): the epoch is
// chosen on an inner region carved out of the training columns, the network never trains there,
// the scored regions play no part in the choice and are measured once, for the chosen weights.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "common/error.h"
#include "data/baselines.h"
#include "data/split.h"
#include "pgm/materials.h"
#include "train/early_stop.h"
#include "train/lookup_fit.h"
#include "train/residual_shrink.h"
#include "train/trainer.h"

using namespace lidarsim;

namespace {

constexpr int kRows = 8, kCols = 256, kFrames = 3, kHalf = 9;  // base 4, depth 1: half-width 9

data::Dataset synthetic() {
  data::Dataset d;
  d.channels = {"range", "class"};
  d.layout = pgm::BeamLayout::uniform(kRows, 1.0, -1.0, kCols);
  d.pgm.resize({kFrames, 2, kRows, kCols});
  d.target.resize({kFrames, 1, kRows, kCols});
  d.mask.resize({kFrames, 1, kRows, kCols});
  const int classes[3] = {pgm::cls::road, pgm::cls::building, pgm::cls::vegetation};
  for (int n = 0; n < kFrames; ++n) {
    d.frames.push_back("synthetic/" + std::to_string(n));
    d.row_modes.push_back("firing_order");
    for (int r = 0; r < kRows; ++r)
      for (int c = 0; c < kCols; ++c) {
        const unsigned h = static_cast<unsigned>(n * 7919 + r * 131 + c * 31) * 2654435761u;
        const int k = static_cast<int>((c / 5 + r + n) % 3);
        const float range = 2.f + static_cast<float>((h >> 8) % 3000) / 100.f;
        d.pgm.at(n, 0, r, c) = range;
        d.pgm.at(n, 1, r, c) = static_cast<float>(classes[k]);
        // Scenery noise a network can memorise: overfitting shows on the inner region.
        d.target.at(n, 0, r, c) = 0.1f + 0.15f * k + 0.004f * range + 0.1f * static_cast<float>((h >> 12) % 100) / 100.f;
        d.mask.at(n, 0, r, c) = (h >> 4) % 10 != 0 ? 1.f : 0.f;
      }
  }
  return d;
}

train::TrainConfig config() {
  train::TrainConfig c;
  c.encoder.channels = {"range", "class"};
  c.base = 4, c.depth = 1;
  c.epochs = 6, c.steps_per_epoch = 15, c.batch = 2, c.lr = 1e-2f;
  c.augment_roll = c.augment_mirror = false;
  c.threads = 1, c.out.clear(), c.progress = false;
  c.early_stop = true;
  c.inner_columns = 8;
  return c;
}

// Sets the target of every cell whose column has `role` in `split` to `value`.
void overwrite(data::Dataset& d, const data::SectorSplit& split, data::Role role, float value) {
  for (int n = 0; n < kFrames; ++n) {
    const auto roles = split.roles(kCols, d.frames[n]);
    for (int r = 0; r < kRows; ++r)
      for (int c = 0; c < kCols; ++c)
        if (roles[c] == role) d.target.at(n, 0, r, c) = value;
  }
}

}  // namespace

TEST(EarlyStop, PicksTheEpochWithTheLowestInnerLossFirstOnTies) {
  train::EarlyStop s;
  const double planted[] = {0.50, 0.41, 0.45, 0.38, 0.38, 0.52, std::numeric_limits<double>::quiet_NaN(), 0.39};
  const bool best[] = {true, true, false, true, false, false, false, false};
  for (int k = 0; k < 8; ++k) EXPECT_EQ(s.add(planted[k]), best[k]) << k;
  EXPECT_EQ(s.best_epoch(), 4);
  EXPECT_DOUBLE_EQ(s.best_loss(), 0.38);
  EXPECT_FALSE(s.exhausted());  // patience 0: every epoch runs
  train::EarlyStop p(2);
  for (int k = 0; k < 5; ++k) p.add(planted[k]);
  EXPECT_FALSE(p.exhausted());  // one epoch without a new best
  p.add(planted[5]);
  EXPECT_TRUE(p.exhausted());
  EXPECT_EQ(train::EarlyStop().best_epoch(), 0);
}

TEST(EarlyStop, ChoosesOnTheInnerRegionKeepsThoseWeightsAndScoresOnce) {
  const data::Dataset d = synthetic();
  const train::TrainResult r = train::train_on(config(), {&d}, {"synthetic"});
  ASSERT_EQ(r.epochs.size(), 6u);
  int argmin = 0;
  for (std::size_t k = 0; k < r.epochs.size(); ++k) {
    ASSERT_TRUE(r.epochs[k].inner.has_value());
    EXPECT_EQ(r.epochs[k].validation.cells, 0);  // the scored regions are not looked at per epoch
    EXPECT_GT(r.epochs[k].inner->cells, 0);
    if (r.epochs[k].inner->mae < r.epochs[static_cast<std::size_t>(argmin)].inner->mae) argmin = static_cast<int>(k);
  }
  EXPECT_EQ(r.chosen_epoch, argmin + 1);
  ASSERT_TRUE(r.chosen_validation.has_value());
  // The returned model is the chosen epoch's: scoring it again gives the reported figure.
  const data::SectorSplit split = data::guarded_split(kHalf, kCols);
  const auto again = data::evaluate_prediction(d, train::predict_dataset(*r.model, config().encoder, d), true, split);
  EXPECT_NEAR(again.mae, r.chosen_validation->mae, 1e-9);
  EXPECT_EQ(again.cells, r.chosen_validation->cells);
  EXPECT_NE(r.inner_region.find("inner region ["), std::string::npos);
  // The inner MAE of the chosen epoch is that of the returned weights on the inner region.
  const auto inner = data::inner_split(split, kHalf, kCols, 8);
  const auto on_inner = data::evaluate_prediction(d, train::predict_dataset(*r.model, config().encoder, d), true, inner);
  EXPECT_NEAR(on_inner.mae, r.epochs[static_cast<std::size_t>(argmin)].inner->mae, 1e-9);
}

TEST(EarlyStop, ScoredCellsDoNotChangeTheChoiceAndInnerCellsDoNotTrain) {
  const data::Dataset d = synthetic();
  const data::SectorSplit split = data::guarded_split(kHalf, kCols);
  const data::SectorSplit inner = data::inner_split(split, kHalf, kCols, 8);
  const train::TrainResult r = train::train_on(config(), {&d}, {"synthetic"});
  // Other targets in the scored regions and their guards: the same run, the same choice.
  data::Dataset scored_changed = d;
  overwrite(scored_changed, split, data::kValidation, 5.f);
  overwrite(scored_changed, split, data::kGuard, 5.f);
  const train::TrainResult s = train::train_on(config(), {&scored_changed}, {"synthetic"});
  ASSERT_EQ(s.epochs.size(), r.epochs.size());
  for (std::size_t k = 0; k < r.epochs.size(); ++k) {
    EXPECT_EQ(s.epochs[k].train_loss, r.epochs[k].train_loss) << k;
    EXPECT_EQ(s.epochs[k].inner->mae, r.epochs[k].inner->mae) << k;
  }
  EXPECT_EQ(s.chosen_epoch, r.chosen_epoch);
  EXPECT_GT(s.chosen_validation->mae, 1.0);  // the changed targets are scored at the end
  // Other targets in the inner region and its band: the same training, other inner losses.
  data::Dataset inner_changed = d;
  overwrite(inner_changed, inner, data::kValidation, 5.f);
  overwrite(inner_changed, inner, data::kGuard, 5.f);
  const train::TrainResult t = train::train_on(config(), {&inner_changed}, {"synthetic"});
  for (std::size_t k = 0; k < r.epochs.size(); ++k) {
    EXPECT_EQ(t.epochs[k].train_loss, r.epochs[k].train_loss) << k;
    EXPECT_GT(t.epochs[k].inner->mae, 1.0) << k;
  }
}

TEST(EarlyStop, PatienceEndsTheRunAndAnUnguardedSplitIsRefused) {
  train::TrainConfig c = config();
  c.patience = 1;
  c.epochs = 12;
  const data::Dataset d = synthetic();
  const train::TrainResult r = train::train_on(c, {&d}, {"synthetic"});
  ASSERT_GT(r.chosen_epoch, 0);
  // Stopped one epoch after the best, unless the best was the last.
  EXPECT_EQ(static_cast<int>(r.epochs.size()), std::min(12, r.chosen_epoch + 1));
  c = config();
  c.split = "interleaved";
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);
}

// With --val (another place held out whole), the inner region is carved out of every --data scan:
// the --val set plays no part until the chosen epoch is scored, and the inner cells do not train.
TEST(EarlyStop, WithSeparateValidationChoosesOnTheTrainingSetsInnerRegionAlone) {
  train::TrainConfig c = config();
  c.epochs = 3;  // four runs: half the epochs of the tests above
  const data::Dataset d = synthetic();
  const data::SectorSplit inner = data::inner_split(data::guarded_split(kHalf, kCols), kHalf, kCols, 8);
  data::Dataset place = synthetic();
  for (std::size_t i = 0; i < place.target.numel(); ++i) place.target.data()[i] = 0.9f - 0.5f * place.target.data()[i];
  const train::TrainResult r = train::train_on(c, {&d}, {"synthetic"}, &place);
  data::Dataset wild = place;
  for (std::size_t i = 0; i < wild.target.numel(); ++i) wild.target.data()[i] = 5.f;  // same place, wild targets
  const train::TrainResult s = train::train_on(c, {&d}, {"synthetic"}, &wild);
  ASSERT_EQ(r.epochs.size(), 3u);
  ASSERT_EQ(s.epochs.size(), r.epochs.size());
  for (std::size_t k = 0; k < r.epochs.size(); ++k) {
    ASSERT_TRUE(r.epochs[k].inner.has_value());
    EXPECT_EQ(r.epochs[k].validation.cells, 0) << k;  // --val is not looked at per epoch
    EXPECT_EQ(s.epochs[k].train_loss, r.epochs[k].train_loss) << k;
    EXPECT_EQ(s.epochs[k].inner->mae, r.epochs[k].inner->mae) << k;
  }
  EXPECT_EQ(s.chosen_epoch, r.chosen_epoch);
  ASSERT_TRUE(r.chosen_validation.has_value() && s.chosen_validation.has_value());
  EXPECT_LT(r.chosen_validation->mae, 1.0);
  EXPECT_GT(s.chosen_validation->mae, 3.0);  // --val is scored once, at the end
  // Every --data column but the inner region and its bands trains: other targets there, the same run.
  data::Dataset inner_changed = d;
  overwrite(inner_changed, inner, data::kValidation, 5.f);
  overwrite(inner_changed, inner, data::kGuard, 5.f);
  const train::TrainResult t = train::train_on(c, {&inner_changed}, {"synthetic"}, &place);
  for (std::size_t k = 0; k < r.epochs.size(); ++k) {
    EXPECT_EQ(t.epochs[k].train_loss, r.epochs[k].train_loss) << k;
    EXPECT_GT(t.epochs[k].inner->mae, 1.0) << k;
  }
  // ... and the training columns do train: other targets there, another run.
  data::Dataset train_changed = d;
  overwrite(train_changed, inner, data::kTrain, 0.f);
  EXPECT_NE(train::train_on(c, {&train_changed}, {"synthetic"}, &place).epochs[0].train_loss, r.epochs[0].train_loss);
}

TEST(EarlyStop, InnerFramesWithAColumnSplitIsAnErrorNotIgnored) {
  train::TrainConfig c = config();
  c.inner_frames = {"000001"};
  const data::Dataset d = synthetic();
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);
}

TEST(EarlyStop, FrameHoldOutChoosesOnWholeInnerFramesThatDoNotTrain) {
  train::TrainConfig c = config();
  c.split = "frames:synthetic/0";
  c.inner_frames = {"synthetic/1"};
  const data::Dataset d = synthetic();
  const train::TrainResult r = train::train_on(c, {&d}, {"synthetic"});
  ASSERT_GT(r.chosen_epoch, 0);
  int argmin = 0;
  for (std::size_t k = 0; k < r.epochs.size(); ++k)
    if (r.epochs[k].inner->mae < r.epochs[static_cast<std::size_t>(argmin)].inner->mae) argmin = static_cast<int>(k);
  EXPECT_EQ(r.chosen_epoch, argmin + 1);
  long frame0 = 0;  // the scored frame: every cell with a return
  for (int k = 0; k < kRows * kCols; ++k) frame0 += d.mask.channel(0, 0)[k] > 0;
  EXPECT_EQ(r.chosen_validation->cells, frame0);
  data::Dataset changed = d;  // the inner frame's targets do not train
  for (int k = 0; k < kRows * kCols; ++k) changed.target.channel(1, 0)[k] = 5.f;
  const train::TrainResult t = train::train_on(c, {&changed}, {"synthetic"});
  for (std::size_t k = 0; k < r.epochs.size(); ++k) EXPECT_EQ(t.epochs[k].train_loss, r.epochs[k].train_loss) << k;
  c.inner_frames.clear();
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);
  c.inner_frames = {"synthetic/0"};  // the scored frame
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);
}

TEST(LookupBaseClasses, KeysTheTableByEveryClass) {
  train::TrainConfig c = config();
  c.early_stop = false;
  c.epochs = 1, c.steps_per_epoch = 1;
  c.lookup_base = true;
  c.lookup_form = "classes";
  const data::Dataset d = synthetic();
  const train::TrainResult r = train::train_on(c, {&d}, {"synthetic"});
  EXPECT_EQ(r.model->config().lookup.classes, pgm::cls::count);
  const auto encoder = pgm::EncoderConfig::from_json(r.meta.attributes.at("encoder"));
  EXPECT_EQ(encoder.class_groups.size(), static_cast<std::size_t>(pgm::cls::count));
  c.lookup_form = "tree";
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);
}

// --shrink-residual: the factor on the network's residual over the table is chosen on the inner
// region alone, the model returned holds it, factor 0 is the table and 1 the network unchanged.
TEST(ShrinkResidual, ChoosesTheFactorOnTheInnerRegionAndTheModelHoldsIt) {
  train::TrainConfig c = config();
  c.lookup_base = true;
  c.shrink_residual = true;
  const data::Dataset d = synthetic();
  const train::TrainResult r = train::train_on(c, {&d}, {"synthetic"});
  ASSERT_TRUE(r.residual_scale.has_value());
  ASSERT_EQ(r.residual_scale_inner_mae.size(), 21u);
  double best = r.residual_scale_inner_mae[0].second, at = r.residual_scale_inner_mae[0].first;
  for (const auto& [factor, mae] : r.residual_scale_inner_mae)
    if (mae < best) best = mae, at = factor;
  EXPECT_DOUBLE_EQ(*r.residual_scale, at);
  // The returned model is the scaled one: its inner MAE is the chosen factor's.
  const data::SectorSplit split = data::guarded_split(kHalf, kCols);
  const auto inner = data::inner_split(split, kHalf, kCols, 8);
  const auto prediction = train::predict_dataset(*r.model, c.encoder, d);
  EXPECT_NEAR(data::evaluate_prediction(d, prediction, true, inner).mae, best, 1e-6);
  EXPECT_NEAR(data::evaluate_prediction(d, prediction, true, split).mae, r.chosen_validation->mae, 1e-9);
  // Factor 0 gives the table back: the same as the untrained model's validation.
  train::scale_residual(*r.model, 0.0);
  const auto table = data::evaluate_prediction(d, train::predict_dataset(*r.model, c.encoder, d), true, split);
  ASSERT_TRUE(r.lookup_validation.has_value());
  EXPECT_NEAR(table.mae, r.lookup_validation->mae, 1e-6);
}

TEST(ShrinkResidual, NeedsALookupBaseAndEarlyStopping) {
  train::TrainConfig c = config();
  c.shrink_residual = true;
  const data::Dataset d = synthetic();
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);  // no lookup base
  c.lookup_base = true;
  c.early_stop = false;
  EXPECT_THROW(train::train_on(c, {&d}, {"synthetic"}), Error);  // no inner region
}

// The mechanism alone, with a made-up inner MAE lowest at 0.3: the model must be left scaled by
// the chosen factor (not by the last one tried, 0), the residual's layer and nothing else.
TEST(ShrinkResidual, TheModelKeepsTheChosenFactorNotTheLastOneTried) {
  train::TrainConfig c = config();
  c.early_stop = false;
  c.epochs = 1;
  c.lookup_base = true;
  const data::Dataset d = synthetic();
  const train::TrainResult r = train::train_on(c, {&d}, {"synthetic"});
  nn::ParamArena& p = r.model->params();
  const int head = p.find("head/weight");
  ASSERT_GE(head, 0);
  const std::size_t n = p.info(head).shape.numel();
  const std::vector<float> trained(p.value(head), p.value(head) + n);
  const std::vector<float> all(p.values(), p.values() + p.size());
  std::size_t k = 0;
  for (std::size_t i = 1; i < n; ++i)
    if (std::abs(trained[i]) > std::abs(trained[k])) k = i;
  ASSERT_GT(std::abs(trained[k]), 1e-6f) << "the head learnt nothing to scale";
  const auto made_up = [&] { return std::abs(p.value(head)[k] / trained[k] - 0.3); };
  const train::ResidualShrink s = train::choose_residual_scale(*r.model, made_up);
  EXPECT_DOUBLE_EQ(s.scale, 0.3);
  for (std::size_t i = 0; i < n; ++i) EXPECT_FLOAT_EQ(p.value(head)[i], static_cast<float>(trained[i] * 0.3)) << i;
  const int bias = p.find("head/bias");
  const std::size_t b0 = p.info(bias).offset, b1 = b0 + p.info(bias).shape.numel();
  for (std::size_t i = 0; i < p.size(); ++i)
    if ((i < p.info(head).offset || i >= p.info(head).offset + n) && (i < b0 || i >= b1)) {
      ASSERT_EQ(p.values()[i], all[i]) << "parameter " << i << " is not part of the residual's last layer";
    }
}
