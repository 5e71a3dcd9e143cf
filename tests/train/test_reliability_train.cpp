// lidar-train's settings: impossible values are refused before anything runs, and a resume
// with a setting that changes the run is refused unless the user names it as an override.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "common/error.h"
#include "data/dataset.h"
#include "train/trainer.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

struct Fixture {
  fs::path dir;
  data::Dataset set;
  Fixture() {
    dir = fs::temp_directory_path() / ("lidarsim_rel_train_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    set.channels = {"range", "class", "material"};
    const auto layout = pgm::BeamLayout::uniform(16, 2.0, -24.0, 64);
    for (int f = 0; f < 2; ++f) {
      pgm::PolarGridMap map(layout, {"range", "class", "material", "intensity", "mask"});
      for (int r = 0; r < map.rows(); ++r)
        for (int c = 0; c < map.cols(); ++c) {
          map.at(0, r, c) = 4.f + r + std::sin(0.1f * c + f);
          map.at(1, r, c) = 40.f;
          map.at(2, r, c) = 1.f;
          map.at(3, r, c) = 0.3f + 0.01f * r;
          map.at(4, r, c) = 1.f;
        }
      set.append(map, "f" + std::to_string(f), "ring");
    }
  }
  ~Fixture() { fs::remove_all(dir); }
  train::TrainConfig config(const std::string& out) const {
    train::TrainConfig c;
    c.base = 2;
    c.depth = 1;
    c.epochs = 1;
    c.steps_per_epoch = 2;
    c.seed = 3;
    c.threads = 1;
    c.out = out.empty() ? fs::path() : dir / out;
    c.progress = false;
    // 64 columns cannot hold the guarded split's guard bands; these tests are about refusing bad
    // settings, not about honest validation.
    c.split = "interleaved";
    return c;
  }
  std::string error(const train::TrainConfig& c) const {
    try {
      train::train_on(c, {&set}, {"set.h5"});
    } catch (const Error& e) {
      return e.what();
    } catch (const std::exception& e) {
      return std::string("not a lidarsim::Error: ") + e.what();
    }
    return "";
  }
};

}  // namespace

TEST(TrainReliability, ImpossibleSettingsAreRefusedNamingTheSetting) {
  Fixture fx;
  EXPECT_EQ(fx.error(fx.config("")), "");
  auto with = [&](auto&& change) {
    train::TrainConfig c = fx.config("");
    change(c);
    return fx.error(c);
  };
  EXPECT_NE(with([](auto& c) { c.steps_per_epoch = -5; }).find("steps-per-epoch"), std::string::npos);
  EXPECT_NE(with([](auto& c) { c.crop_columns = -64; }).find("crop"), std::string::npos);
  EXPECT_NE(with([](auto& c) { c.crop_columns = 7; }).find("crop"), std::string::npos);
  EXPECT_NE(with([](auto& c) { c.threads = 0; }).find("threads"), std::string::npos);
  EXPECT_NE(with([](auto& c) { c.depth = 0; }).find("depth"), std::string::npos);
  EXPECT_NE(with([](auto& c) { c.base = 0; }).find("base"), std::string::npos);
  EXPECT_NE(with([](auto& c) { c.batch = 1000000000; }).find("batch"), std::string::npos);
}

TEST(TrainReliability, ResumeWithAnotherSeedLrBatchOrAugmentationIsRefused) {
  Fixture fx;
  train::TrainConfig first = fx.config("ck.h5");
  ASSERT_EQ(fx.error(first), "");
  auto resumed = [&](auto&& change) {
    train::TrainConfig c = fx.config("ck.h5");
    c.epochs = 1;
    c.resume = true;
    change(c);
    return fx.error(c);
  };
  EXPECT_EQ(resumed([](auto&) {}), "");
  EXPECT_NE(resumed([](auto& c) { c.seed = 4; }).find("seed"), std::string::npos);
  EXPECT_NE(resumed([](auto& c) { c.lr = 0.1f; }).find("lr"), std::string::npos);
  EXPECT_NE(resumed([](auto& c) { c.batch = 2; }).find("batch"), std::string::npos);
  EXPECT_NE(resumed([](auto& c) { c.augment_mirror = false; }).find("augment_mirror"), std::string::npos);
  EXPECT_NE(resumed([](auto& c) { c.lambda = 1.f; }).find("lambda"), std::string::npos);
}
