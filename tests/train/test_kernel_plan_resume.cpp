// A training run records its kernel plan (nn/kernel_plan.h) in its checkpoint, and a resume takes
// exactly those choices: after the cache file changed under it, the resumed run still ends with
// the uninterrupted run's checkpoint, byte for byte. A run that does read the changed cache ends
// with other bits, so the comparison can fail.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

#include "data/dataset.h"
#include "nn/checkpoint.h"
#include "nn/kernel_cache.h"
#include "pgm/beam_layout.h"
#include "pgm/materials.h"
#include "pgm/polar_grid_map.h"
#include "tests/support/temp_path.h"
#include "train/trainer.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

struct ResumePlanCache {
  fs::path dir = lidarsim::testing::temp_path("kernel_plan_resume_cache");
  ResumePlanCache() {
    fs::remove_all(dir);
    fs::create_directories(dir);
    ::setenv("LIDARSIM_KERNEL_CACHE", dir.c_str(), 1);
  }
  ~ResumePlanCache() { ::unsetenv("LIDARSIM_KERNEL_CACHE"); }
};

data::Dataset resume_plan_dataset(int frames) {
  data::Dataset d;
  d.channels = {"range", "class", "material"};
  const auto layout = pgm::BeamLayout::uniform(16, 2.0, -24.0, 64);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int f = 0; f < frames; ++f) {
    pgm::PolarGridMap map(layout, {"range", "class", "material", "intensity", "mask"});
    for (int r = 0; r < map.rows(); ++r)
      for (int c = 0; c < map.cols(); ++c) {
        const int cls = ((c + 3 * f) / 8) % 2 ? pgm::cls::road : pgm::cls::car;
        map.at(map.channel_index("range"), r, c) = 5.f + 2.f * r;
        map.at(map.channel_index("class"), r, c) = static_cast<float>(cls);
        map.at(map.channel_index("material"), r, c) = static_cast<float>(pgm::default_material(cls));
        map.at(map.channel_index("intensity"), r, c) = (cls == pgm::cls::car ? 0.5f : 0.3f) + 0.1f * float(u(rng));
        map.at(map.channel_index("mask"), r, c) = 1.f;
      }
    d.append(map, "plan/" + std::to_string(f), "ring");
  }
  return d;
}

std::string resume_plan_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

// Every fp32 choice in the cache file swapped (direct <-> winograd): what a cache measured under
// other load, or on another machine of the same kind, might hold.
void flip_cache(const fs::path& path) {
  nlohmann::json j = nlohmann::json::parse(resume_plan_bytes(path));
  for (auto& c : j.at("choices")) {
    const std::string a = c.at("algo");
    if (a == "direct") c["algo"] = "winograd";
    else if (a == "winograd") c["algo"] = "direct";
  }
  std::ofstream(path) << j.dump();
}

}  // namespace

TEST(KernelPlanResume, AResumeTakesTheCheckpointsPlanAfterTheCacheChanged) {
  const ResumePlanCache cache;
  const fs::path dir = lidarsim::testing::temp_path("kernel_plan_resume");
  fs::remove_all(dir);
  fs::create_directories(dir);
  data::write_dataset(dir / "frames.h5", resume_plan_dataset(3));
  train::TrainConfig c;
  c.encoder.channels = {"range", "class", "material"};
  c.base = 4, c.depth = 2, c.epochs = 2, c.steps_per_epoch = 5, c.batch = 2, c.seed = 11, c.threads = 2;
  c.split = "interleaved";
  c.progress = false;
  c.kernels = nn::PlanMode::calibrated;
  c.data = {dir / "frames.h5"};
  c.out = dir / "through.h5";
  train::train(c);  // measures each shape and writes the cache
  const fs::path cache_file = nn::kernel_cache_path(nn::active_isa());
  ASSERT_TRUE(fs::exists(cache_file));
  const nn::Checkpoint meta = nn::read_checkpoint_meta(c.out);
  ASSERT_EQ(meta.attributes.count("kernel_plan"), 1u);
  EXPECT_NE(meta.attributes.at("kernel_plan").find("\"mode\":\"calibrated\""), std::string::npos);

  c.out = dir / "resumed.h5";
  const auto first = train::train(c, [](const train::EpochReport& r) {
    if (r.epoch == 1) train::stop_requested().store(true);
  });
  train::stop_requested().store(false);
  ASSERT_TRUE(first.interrupted);
  flip_cache(cache_file);
  c.resume = true;
  train::train(c);
  EXPECT_TRUE(resume_plan_bytes(dir / "through.h5") == resume_plan_bytes(dir / "resumed.h5"))
      << "the resumed run did not take the checkpoint's kernel plan";

  // The changed cache does change the bits of a run that reads it: the check above can fail.
  c.resume = false;
  c.out = dir / "flipped.h5";
  train::train(c);
  EXPECT_FALSE(resume_plan_bytes(dir / "through.h5") == resume_plan_bytes(dir / "flipped.h5"));
}

TEST(KernelPlanResume, RuleModeIsRecordedToo) {
  const ResumePlanCache cache;
  const fs::path dir = lidarsim::testing::temp_path("kernel_plan_rule");
  fs::remove_all(dir);
  fs::create_directories(dir);
  data::write_dataset(dir / "frames.h5", resume_plan_dataset(2));
  train::TrainConfig c;
  c.encoder.channels = {"range", "class", "material"};
  c.base = 4, c.depth = 1, c.epochs = 1, c.steps_per_epoch = 2, c.batch = 1, c.threads = 2;
  c.split = "interleaved";
  c.progress = false;
  c.data = {dir / "frames.h5"};
  c.out = dir / "rule.h5";
  const auto result = train::train(c);
  EXPECT_EQ(result.model->kernel_plan().mode(), nn::PlanMode::rule);
  EXPECT_FALSE(result.model->kernel_plan().entries().empty());
  EXPECT_NE(nn::read_checkpoint_meta(c.out).attributes.at("kernel_plan").find("\"mode\":\"rule\""), std::string::npos);
  EXPECT_TRUE(fs::is_empty(cache.dir));  // rule mode never touches the cache
}
