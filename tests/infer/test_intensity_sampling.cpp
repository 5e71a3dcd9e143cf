// Intensity drawn from a spread head (infer/intensity_sampling.h, IntensityModel::sample_from_spread):
// deterministic in (seed, frame, cell), distributed as predicted, clamped; the mean by default.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "common/error.h"
#include "infer/intensity_model.h"
#include "infer/intensity_sampling.h"
#include "nn/checkpoint.h"
#include "nn/unet.h"
#include "pgm/encoder.h"
#include "tests/support/temp_path.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

// An untrained checkpoint with the given heads (weights from a seed: the test is about sampling).
fs::path checkpoint(const std::string& name, const std::vector<nn::HeadKind>& heads) {
  const fs::path dir = lidarsim::testing::temp_path("sampling_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  pgm::EncoderConfig encoder;
  encoder.channels = {"range", "class", "material"};
  nn::UNetConfig config{encoder.input_channels(), static_cast<int>(std::max<std::size_t>(1, heads.size())), 4, 2, 0};
  if (heads.size() > 1) config.heads = heads;
  nn::UNet model(config);
  model.init(7);
  nn::Checkpoint meta;
  meta.attributes["encoder"] = encoder.to_json();
  nn::save_checkpoint(dir / "ck.h5", model, nullptr, meta);
  return dir / "ck.h5";
}

pgm::PolarGridMap scan() {
  pgm::PolarGridMap map(pgm::BeamLayout::uniform(16, 2.0, -24.0, 64), {"range", "class", "material", "intensity", "mask"});
  for (int r = 0; r < map.rows(); ++r)
    for (int c = 0; c < map.cols(); ++c) {
      if ((r + c) % 7 == 0) continue;  // cells without a return
      map.at(map.channel_index("range"), r, c) = 5.f + r + 0.1f * c;
      map.at(map.channel_index("class"), r, c) = static_cast<float>(c % 16 < 8 ? pgm::cls::car : pgm::cls::road);
      map.at(map.channel_index("material"), r, c) = 1.f;
      map.at(map.channel_index("mask"), r, c) = 1.f;
    }
  return map;
}

}  // namespace

TEST(IntensitySampling, DrawsDependOnlyOnSeedFrameAndCell) {
  const infer::IntensitySampling a{1}, b{2};
  int differ_seed = 0, differ_frame = 0;
  for (std::uint64_t cell = 0; cell < 1000; ++cell) {
    const float x = infer::sample_intensity(nn::HeadKind::log_scale_laplace, 0.4f, 0.1f, a, 3, cell);
    EXPECT_EQ(x, infer::sample_intensity(nn::HeadKind::log_scale_laplace, 0.4f, 0.1f, a, 3, cell));
    differ_seed += x != infer::sample_intensity(nn::HeadKind::log_scale_laplace, 0.4f, 0.1f, b, 3, cell);
    differ_frame += x != infer::sample_intensity(nn::HeadKind::log_scale_laplace, 0.4f, 0.1f, a, 4, cell);
  }
  EXPECT_GT(differ_seed, 900);
  EXPECT_GT(differ_frame, 900);
}

// 20,000 draws: the median |x - mean| is b log 2 (Laplace) or 0.674 sigma (Gaussian), the mean of
// the draws the mean; draws stay inside the clamp range.
TEST(IntensitySampling, DrawsHaveThePredictedSpreadAndStayInRange) {
  const infer::IntensitySampling s{5, 0.f, 1.f};
  for (const auto& [kind, quantile] : {std::pair{nn::HeadKind::log_scale_laplace, std::log(2.0)},
                                      std::pair{nn::HeadKind::log_scale_gaussian, 0.6744898}}) {
    std::vector<double> dev;
    double sum = 0;
    for (std::uint64_t cell = 0; cell < 20000; ++cell) {
      const float x = infer::sample_intensity(kind, 0.5f, 0.05f, s, 0, cell);
      dev.push_back(std::abs(x - 0.5));
      sum += x;
    }
    std::nth_element(dev.begin(), dev.begin() + 10000, dev.end());
    EXPECT_NEAR(dev[10000] / 0.05, quantile, 0.03) << nn::head_name(kind);
    EXPECT_NEAR(sum / 20000, 0.5, 0.002) << nn::head_name(kind);
  }
  for (std::uint64_t cell = 0; cell < 2000; ++cell) {
    const float x = infer::sample_intensity(nn::HeadKind::log_scale_gaussian, 0.95f, 0.5f, s, 0, cell);
    EXPECT_GE(x, 0.f);
    EXPECT_LE(x, 1.f);
  }
}

// Without --sample-intensity the model's output is the mean channel, bit for bit; with it, the
// draws are the same for the same seed and frame and change with either.
TEST(IntensitySampling, ModelSamplesOnlyWhenAskedAndDeterministically) {
  const fs::path ck = checkpoint("laplace", {nn::HeadKind::mean, nn::HeadKind::log_scale_laplace});
  const pgm::PolarGridMap map = scan();
  infer::IntensityModel model = infer::IntensityModel::load(ck);
  ASSERT_TRUE(model.spread());
  std::vector<float> mean, again;
  model.predict(map, mean);
  // The mean is channel 0 of the network's output.
  nn::UNet raw(nn::read_checkpoint_meta(ck).unet);
  nn::load_checkpoint(ck, raw, nullptr);
  nn::Tensor input(1, model.encoder().input_channels(), map.rows(), map.cols()), out;
  pgm::encode_input(pgm::view_of(map), model.encoder(), input, 0);
  raw.predict(input, out);
  const float* mask = map.channel("mask");
  for (std::size_t i = 0; i < map.cells(); ++i) ASSERT_EQ(mean[i], mask[i] > 0 ? out.data()[i] : 0.f) << i;

  model.sample_from_spread({11}, "test");
  std::vector<float> a, b, c, d;
  model.predict(map, a, 0);
  model.predict(map, b, 0);
  model.predict(map, c, 1);
  EXPECT_EQ(a, b);
  EXPECT_NE(a, c);
  model.sample_from_spread({12}, "test");
  model.predict(map, d, 0);
  EXPECT_NE(a, d);
  for (std::size_t i = 0; i < map.cells(); ++i) {
    if (mask[i] <= 0) {
      EXPECT_EQ(a[i], 0.f);
    }
    EXPECT_GE(a[i], 0.f);
    EXPECT_LE(a[i], 1.f);
  }
}

TEST(IntensitySampling, AModelWithoutASpreadHeadIsRefusedByName) {
  const fs::path ck = checkpoint("mean", {});
  infer::IntensityModel model = infer::IntensityModel::load(ck);
  EXPECT_FALSE(model.spread());
  try {
    model.sample_from_spread({1}, "lidar-infer predict: --sample-intensity");
    FAIL() << "no error";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(ck.string()), std::string::npos) << what;
    EXPECT_NE(what.find("--sample-intensity needs a spread head (heads: mean)"), std::string::npos) << what;
  }
}

// A calibrated checkpoint (nn::UNetConfig::spread_scale, train/spread_metrics.h calibrate_spread)
// draws with its scale times the factor: same seed, frame and cell, the draw's distance from the
// mean is the factor times the uncalibrated one wherever neither is clamped to 0..1.
TEST(IntensitySampling, ACalibratedCheckpointDrawsWithItsFactor) {
  const fs::path untrained = checkpoint("calibrated", {nn::HeadKind::mean, nn::HeadKind::log_scale_laplace});
  const nn::Checkpoint meta = nn::read_checkpoint_meta(untrained);
  // Outputs = the head's biases: mean 0.5, scale 0.02 (draws rarely reach the clamp).
  nn::UNet raw(meta.unet);
  std::fill(raw.params().values(), raw.params().values() + raw.params().size(), 0.f);
  float* bias = raw.params().value(raw.params().find("head/bias"));
  bias[0] = 0.5f, bias[1] = std::log(0.02f);
  const fs::path ck = untrained.parent_path() / "plain.h5", calibrated = untrained.parent_path() / "calibrated.h5";
  nn::save_checkpoint(ck, raw, nullptr, meta);
  raw.set_spread_scale(2.5f);
  nn::save_checkpoint(calibrated, raw, nullptr, meta);
  const pgm::PolarGridMap map = scan();
  infer::IntensityModel plain = infer::IntensityModel::load(ck), wide = infer::IntensityModel::load(calibrated);
  std::vector<float> mean, a, b;
  plain.predict(map, mean);
  plain.sample_from_spread({3}, "test");
  wide.sample_from_spread({3}, "test");
  plain.predict(map, a, 2);
  wide.predict(map, b, 2);
  int compared = 0;
  for (std::size_t i = 0; i < map.cells(); ++i) {
    if (map.channel("mask")[i] <= 0 || b[i] <= 0.f || b[i] >= 1.f || a[i] <= 0.f || a[i] >= 1.f) continue;
    EXPECT_NEAR(b[i] - mean[i], 2.5f * (a[i] - mean[i]), 1e-5f) << i;
    ++compared;
  }
  EXPECT_GT(compared, 500);
}
