// lidar-train: learning on a real scan, exact resume, clear errors.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>

#include "common/error.h"
#include "data/baselines.h"
#include "data/dataset.h"
#include "data/import.h"
#include "tests/support/file_bytes.h"
#include "tests/support/shared_data.h"
#include "tests/support/temp_path.h"
#include "train/trainer.h"

using lidarsim::testing::read_bytes;

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

fs::path train_temp_dir(const std::string& name) {
  const fs::path dir = lidarsim::testing::temp_path("train_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// A small synthetic dataset: 16 x 64 grids where intensity depends on class and range.
fs::path synthetic_dataset(const fs::path& dir, int frames) {
  data::Dataset d;
  d.channels = {"range", "class", "material"};
  const auto layout = pgm::BeamLayout::uniform(16, 2.0, -24.0, 64);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> range(-1.f, 1.f);
  for (int f = 0; f < frames; ++f) {
    pgm::PolarGridMap map(layout, {"range", "class", "material", "intensity", "mask"});
    for (int r = 0; r < map.rows(); ++r)
      for (int c = 0; c < map.cols(); ++c) {
        if ((r * 7 + c * 3 + f) % 5 == 0) continue;  // some empty cells
        // Smooth over the grid, as real scenes are; the frame index shifts it.
        const float rg = 4.f + 3.f * r + 8.f * std::sin(0.1f * c + f) + 0.2f * range(rng);
        const int cls = (c / 8) % 2 ? pgm::cls::road : pgm::cls::car;
        map.at(map.channel_index("range"), r, c) = rg;
        map.at(map.channel_index("class"), r, c) = static_cast<float>(cls);
        map.at(map.channel_index("material"), r, c) = static_cast<float>(pgm::default_material(cls));
        map.at(map.channel_index("intensity"), r, c) = (cls == pgm::cls::car ? 0.6f : 0.2f) - rg / 200.f;
        map.at(map.channel_index("mask"), r, c) = 1.f;
      }
    d.append(map, "synthetic/" + std::to_string(f), "ring");
  }
  const fs::path path = dir / "synthetic.h5";
  data::write_dataset(path, d);
  return path;
}

train::TrainConfig train_small_config(const fs::path& data, const fs::path& out) {
  train::TrainConfig c;
  c.data = {data};
  c.base = 4;
  c.depth = 2;
  c.epochs = 4;
  c.steps_per_epoch = 3;
  c.batch = 2;
  c.lr = 3e-3f;
  c.seed = 11;
  c.threads = 2;
  c.out = out;
  c.progress = false;
  // 64 columns are too few for guard bands of a depth-2 UNet (2 x 23 columns on each side); these
  // tests are about the training mechanics, not about honest validation.
  c.split = "interleaved";
  return c;
}

}  // namespace

TEST(Train, ResumedRunEndsWithByteIdenticalCheckpoint) {
  const fs::path dir = train_temp_dir("resume");
  const fs::path data = synthetic_dataset(dir, 3);

  train::TrainConfig straight = train_small_config(data, dir / "straight.h5");
  train::train(straight);

  // The same run, stopped after its second epoch (as Ctrl-C would), then resumed.
  train::TrainConfig split = train_small_config(data, dir / "split.h5");
  const auto first = train::train(split, [](const train::EpochReport& r) {
    if (r.epoch == 2) train::stop_requested().store(true);
  });
  train::stop_requested().store(false);
  ASSERT_TRUE(first.interrupted);
  ASSERT_EQ(first.steps, 6);
  split.resume = true;
  const auto second = train::train(split);
  EXPECT_FALSE(second.interrupted);
  EXPECT_EQ(second.steps, 12);
  EXPECT_EQ(read_bytes(dir / "straight.h5"), read_bytes(dir / "split.h5"));
}

TEST(Train, InterruptMidEpochSavesTheCurrentStepAndResumesExactly) {
  const fs::path dir = train_temp_dir("midepoch");
  const fs::path data = synthetic_dataset(dir, 3);
  train::TrainConfig straight = train_small_config(data, dir / "straight.h5");
  straight.epochs = 2;
  train::train(straight);

  train::TrainConfig split = train_small_config(data, dir / "split.h5");
  split.epochs = 2;
  train::stop_requested().store(true);  // stops after the very first step
  const auto first = train::train(split);
  train::stop_requested().store(false);
  ASSERT_TRUE(first.interrupted);
  ASSERT_EQ(first.steps, 1);
  split.resume = true;
  train::train(split);
  EXPECT_EQ(read_bytes(dir / "straight.h5"), read_bytes(dir / "split.h5"));
}

// Statistical: 30 epochs judged by their validation error (normal pass only; Train.* below and
// TrainStatistical's smoke run cover the code).
TEST(TrainStatistical, ValidationErrorFallsOnASyntheticClassRangeRule) {
  const fs::path dir = train_temp_dir("learns");
  train::TrainConfig c = train_small_config(synthetic_dataset(dir, 3), dir / "ck.h5");
  c.epochs = 30;
  c.steps_per_epoch = 10;
  c.base = 8;
  c.lr = 1e-2f;
  double class_mean = 0;
  for (const auto& b : data::evaluate_baselines(data::read_dataset(c.data[0])))
    if (b.name == "class_mean") class_mean = b.validation.mae;
  const auto result = train::train(c);
  ASSERT_EQ(result.epochs.size(), 30u);
  // Range explains most of what class leaves: the network must find it.
  std::printf("val MAE %.4f, class-mean baseline %.4f\n", result.epochs.back().validation.mae, class_mean);
  EXPECT_LT(result.epochs.back().validation.mae, 0.6 * class_mean);
}

TEST(Train, ResumingWithAnotherArchitectureNamesTheCheckpoint) {
  const fs::path dir = train_temp_dir("mismatch");
  train::TrainConfig c = train_small_config(synthetic_dataset(dir, 2), dir / "ck.h5");
  c.epochs = 1;
  train::train(c);
  c.base = 8;
  c.resume = true;
  try {
    train::train(c);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("ck.h5"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("architecture"), std::string::npos) << e.what();
  }
}

TEST(Train, MissingInputChannelNamesTheDatasetAndTheChannel) {
  const fs::path dir = train_temp_dir("channel");
  train::TrainConfig c = train_small_config(synthetic_dataset(dir, 1), dir / "ck.h5");
  c.encoder.channels = {"range", "class", "incidence"};
  try {
    train::train(c);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("synthetic.h5"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("incidence"), std::string::npos) << e.what();
  }
}

// The CI smoke test on real data: one real SemanticKITTI scan, a small UNet, well under a minute;
// the validation MAE on the guarded split (lidar-train's default) must end below the
// per-class-mean baseline on the same cells.
TEST(TrainStatistical, SmokeOnARealScanBeatsThePerClassMeanBaseline) {
  LIDARSIM_REQUIRE_SHARED_DATA(scans, "semantickitti-seq00-sample");
  const fs::path dir = train_temp_dir("smoke");
  data::ImportOptions import;
  import.max_frames = 1;
  import.extra_channels = {};
  const data::Dataset dataset = data::import_semantickitti(scans, import);
  data::write_dataset(dir / "scan.h5", dataset);
  double class_mean = 0;
  for (const auto& b : data::evaluate_baselines(dataset, data::guarded_split(51, dataset.cols())))
    if (b.name == "class_mean") class_mean = b.validation.mae;
  ASSERT_GT(class_mean, 0.05);

  train::TrainConfig c;
  c.data = {dir / "scan.h5"};
  c.base = 8;
  c.depth = 3;
  c.epochs = 12;
  c.steps_per_epoch = 25;
  c.crop_columns = 256;
  c.batch = 2;
  c.lr = 4e-3f;
  c.threads = 2;
  c.out = dir / "ck.h5";
  c.progress = false;
  const auto result = train::train(c);
  const double mae = result.epochs.back().validation.mae;
  std::printf("smoke: val MAE %.4f vs per-class mean %.4f\n", mae, class_mean);
  EXPECT_LT(mae, class_mean);
}
