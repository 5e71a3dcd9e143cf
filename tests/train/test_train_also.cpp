// --train-also (train/trainer.h, train_also): scans of other places train in every cell and are
// never scored, while the --data sets keep their split.
#include <gtest/gtest.h>

#include "data/baselines.h"
#include "data/frame_source.h"
#include "data/split.h"
#include "train/frame_batches.h"
#include "train/trainer.h"

using namespace lidarsim;

namespace {

constexpr int kAlsoRows = 4, kAlsoCols = 256;

data::Dataset flat(float intensity, const std::string& place) {
  data::Dataset d;
  d.channels = {"range"};
  d.layout = pgm::BeamLayout::uniform(kAlsoRows, 1.0, -1.0, kAlsoCols);
  d.pgm.resize({2, 1, kAlsoRows, kAlsoCols});
  d.target.resize({2, 1, kAlsoRows, kAlsoCols});
  d.mask.resize({2, 1, kAlsoRows, kAlsoCols});
  for (int n = 0; n < 2; ++n) {
    d.frames.push_back(place + "/" + std::to_string(n));
    d.row_modes.push_back("firing_order");
    for (int r = 0; r < kAlsoRows; ++r)
      for (int c = 0; c < kAlsoCols; ++c) {
        d.pgm.at(n, 0, r, c) = 10.f + c % 7;
        d.target.at(n, 0, r, c) = intensity;
        d.mask.at(n, 0, r, c) = 1.f;
      }
  }
  return d;
}

}  // namespace

TEST(TrainAlso, OtherPlacesTrainInEveryColumnAndAreNeverScored) {
  const data::Dataset here = flat(0.2f, "here"), there = flat(0.6f, "there");
  const data::SectorSplit split = data::guarded_split(9, kAlsoCols);
  const auto a = data::memory_frame_source(here, "here"), b = data::memory_frame_source(there, "there");
  pgm::EncoderConfig encoder;
  encoder.channels = {"range"};
  const train::TrainingFrames frames({a.get(), b.get()}, encoder, split, 1);
  nn::Tensor x(nn::Shape{1, 1, kAlsoRows, kAlsoCols}), y(nn::Shape{1, 1, kAlsoRows, kAlsoCols}), m(nn::Shape{1, 1, kAlsoRows, kAlsoCols});
  const auto roles = split.roles(kAlsoCols, "here/0");
  long trained_here = 0, trained_there = 0;
  frames.fill(train::Sample{0, 0, false}, x, y, m, 0);
  for (float v : m) trained_here += v > 0;
  frames.fill(train::Sample{2, 0, false}, x, y, m, 0);  // frame 0 of "there"
  for (float v : m) trained_there += v > 0;
  long train_columns = 0, validation_columns = 0;
  for (auto role : roles) train_columns += role == data::kTrain, validation_columns += role == data::kValidation;
  EXPECT_EQ(trained_here, train_columns * kAlsoRows);
  EXPECT_EQ(trained_there, static_cast<long>(kAlsoCols) * kAlsoRows);

  // Scored: the validation columns of "here" only (both of its frames).
  train::TrainConfig c;
  c.encoder = encoder;
  c.base = 4, c.depth = 1;
  c.epochs = 1, c.steps_per_epoch = 2, c.batch = 1;
  c.threads = 1, c.out.clear(), c.progress = false;
  c.train_also = {"there.h5"};
  const train::TrainResult r = train::train_on(c, {&here, &there}, {"here", "there"});
  EXPECT_EQ(r.epochs.back().validation.cells, 2 * validation_columns * kAlsoRows);
}
