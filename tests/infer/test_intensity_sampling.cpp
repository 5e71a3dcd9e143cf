// Intensity drawn from a spread head (infer/intensity_sampling.h, IntensityModel::sample_from_spread):
// deterministic in (seed, frame, cell), distributed as predicted, clamped; the mean by default.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "common/error.h"
#include "infer/intensity_model.h"
#include "infer/intensity_sampling.h"
#include "nn/checkpoint.h"
#include "nn/checkpoint_weights.h"
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

namespace {

// A residual table by hand (nn::SpreadResidual): two bins of the mean split at 0.3; below it z is
// the quantile function of `low`, above it of `high`, at (k + 0.5) / levels.
template <class Low, class High>
nn::SpreadResidual table(Low low, High high, float step, int levels = 256) {
  nn::SpreadResidual r;
  r.levels = levels;
  r.mean_edges = {0.3f};
  for (int k = 0; k < levels; ++k) r.z.push_back(static_cast<float>(low((k + 0.5) / levels)));
  for (int k = 0; k < levels; ++k) r.z.push_back(static_cast<float>(high((k + 0.5) / levels)));
  r.target_step = step;
  return r;
}

// 40 equal bins of 0.025 plus the two ends: sum of min(p, q), as qualify/similarity.h does it. The
// edges sit between the 0.01 grid's values (from -0.005), as a bench's percentile edges do.
double intersection(const std::vector<double>& a, const std::vector<double>& b) {
  std::vector<double> ha(42), hb(42);
  const auto bin = [](double x) {
    const double t = (x + 0.005) * 40;
    return t < 0 ? 0 : t >= 40 ? 41 : 1 + std::min(39, static_cast<int>(t));
  };
  for (double x : a) ha[static_cast<std::size_t>(bin(x))] += 1.0 / a.size();
  for (double x : b) hb[static_cast<std::size_t>(bin(x))] += 1.0 / b.size();
  double s = 0;
  for (std::size_t k = 0; k < ha.size(); ++k) s += std::min(ha[k], hb[k]);
  return s;
}

}  // namespace

// Known truth: "measured" intensity = mean + 0.1 z, clamped to 0..1 and reported on a 0.01 grid,
// where z's shape depends on the mean (below 0.3 a skewed exponential, above it a narrow uniform).
// Drawn through the table of that truth, the histogram matches the measured one (intersection
// >= 0.95; 40 bins of 0.025 hold 2 or 3 grid values each, so a draw off the grid would not); the
// head's Laplace with the likelihood's best scale cannot (< 0.85).
TEST(IntensitySampling, AResidualTableReproducesAShapeThatDependsOnTheMean) {
  const auto low = [](double u) { return -std::log(1 - u) - 1; };  // exponential - 1: skewed, mean 0
  const auto high = [](double u) { return 0.8 * (2 * u - 1); };    // uniform on [-0.8, 0.8]
  const nn::SpreadResidual r = table(low, high, 0.01f);
  const infer::IntensitySampling s{9, 0.f, 1.f};
  std::vector<double> measured, empirical, laplace;
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  double abs_sum = 0;
  std::vector<float> means;
  for (int i = 0; i < 40000; ++i) means.push_back(i % 2 ? 0.15f + 0.1f * (i % 7) / 7 : 0.4f + 0.2f * (i % 11) / 11);
  for (std::size_t i = 0; i < means.size(); ++i) {
    const double z = means[i] < 0.3f ? low(u(rng)) : high(u(rng));
    // As a sensor file holds it: a float on the grid.
    measured.push_back(static_cast<float>(std::clamp(std::round((means[i] + 0.1 * z) * 100) / 100, 0.0, 1.0)));
    abs_sum += std::abs(measured.back() - means[i]);
  }
  const float b = static_cast<float>(abs_sum / means.size());  // the Laplace's best scale for these cells
  for (std::size_t i = 0; i < means.size(); ++i) {
    const float x = infer::sample_intensity_empirical(r, means[i], 0.1f, s, 0, i);
    EXPECT_NEAR(x * 100, std::round(x * 100), 1e-3) << "on the grid";
    empirical.push_back(x);
    laplace.push_back(infer::sample_intensity(nn::HeadKind::log_scale_laplace, means[i], b, s, 0, i));
  }
  EXPECT_GE(intersection(empirical, measured), 0.95);
  EXPECT_LT(intersection(laplace, measured), 0.85);
}

// The table travels in the checkpoint (format 4) and in the weights file (format 3), and the model
// draws through it: with every quantile 2, a draw is the mean + 2 scales, put on the grid.
// --parametric-style sampling (IntensitySampling::parametric) still draws the Laplace.
TEST(IntensitySampling, ACheckpointWithAResidualTableDrawsThroughIt) {
  const fs::path untrained = checkpoint("table", {nn::HeadKind::mean, nn::HeadKind::log_scale_laplace});
  const nn::Checkpoint meta = nn::read_checkpoint_meta(untrained);
  // Outputs = the head's biases: mean 0.503, scale 0.02, so every draw is 0.543, off the grid.
  nn::UNet raw(meta.unet);
  std::fill(raw.params().values(), raw.params().values() + raw.params().size(), 0.f);
  float* bias = raw.params().value(raw.params().find("head/bias"));
  bias[0] = 0.503f, bias[1] = std::log(0.02f);
  nn::SpreadResidual r = table([](double) { return 2.0; }, [](double) { return 2.0; }, 0.01f, 4);
  raw.set_spread_residual(r);
  const fs::path ck = untrained.parent_path() / "with_table.h5", weights = untrained.parent_path() / "with_table.bin";
  nn::save_checkpoint(ck, raw, nullptr, meta);
  nn::save_weights(weights, raw, meta.attributes);
  EXPECT_EQ(nn::read_checkpoint_meta(ck).unet.spread_residual, r);
  const pgm::PolarGridMap map = scan();
  for (const fs::path& file : {ck, weights}) {
    infer::IntensityModel model = infer::IntensityModel::load(file);
    std::vector<float> mean, scale, drawn, laplace;
    model.predict_distribution(map, mean, scale);
    model.sample_from_spread({5}, "test");
    model.predict(map, drawn, 1);
    model.sample_from_spread({5, 0.f, 1.f, true}, "test");
    model.predict(map, laplace, 1);
    int differ = 0;
    for (std::size_t i = 0; i < map.cells(); ++i) {
      if (map.channel("mask")[i] <= 0) continue;
      const double want = std::clamp(std::round(std::clamp(mean[i] + 2.0 * scale[i], 0.0, 1.0) * 100) / 100, 0.0, 1.0);
      ASSERT_NEAR(drawn[i], want, 1e-6) << file << " cell " << i;
      differ += laplace[i] != drawn[i];
    }
    EXPECT_GT(differ, 100) << file;
  }
}

// A zero head (nn/heads.h zero_logit, checkpoint format 5, weights format 4): a draw is 0 with the
// head's probability, from a uniform independent of the spread's; otherwise mean / (1 - p0) plus
// the table's draw (the table describes the values that are not 0, around that centre).
TEST(IntensitySampling, AZeroHeadDrawsZeroWithItsProbabilityAndCentresTheRest) {
  const fs::path untrained = checkpoint("zero", {nn::HeadKind::mean, nn::HeadKind::log_scale_laplace, nn::HeadKind::zero_logit});
  const nn::Checkpoint meta = nn::read_checkpoint_meta(untrained);
  EXPECT_EQ(meta.unet.heads.size(), 3u);
  // Outputs = the head's biases: mean 0.28, scale 0.02, P(0) = 0.3.
  nn::UNet raw(meta.unet);
  std::fill(raw.params().values(), raw.params().values() + raw.params().size(), 0.f);
  float* bias = raw.params().value(raw.params().find("head/bias"));
  bias[0] = 0.28f, bias[1] = std::log(0.02f), bias[2] = static_cast<float>(std::log(0.3 / 0.7));
  raw.set_spread_residual(table([](double) { return 2.0; }, [](double) { return 2.0; }, 0.01f, 4));
  const fs::path ck = untrained.parent_path() / "zero_table.h5", weights = untrained.parent_path() / "zero_table.bin";
  nn::save_checkpoint(ck, raw, nullptr, meta);
  nn::save_weights(weights, raw, meta.attributes);
  const pgm::PolarGridMap map = scan();
  for (const fs::path& file : {ck, weights}) {
    infer::IntensityModel model = infer::IntensityModel::load(file);
    std::vector<float> mean, scale, drawn;
    model.predict_distribution(map, mean, scale);
    long zeros = 0, cells = 0;
    for (int frame = 0; frame < 4; ++frame) {
      model.sample_from_spread({9}, "test");
      model.predict(map, drawn, static_cast<std::uint64_t>(frame));
      for (std::size_t i = 0; i < map.cells(); ++i) {
        if (map.channel("mask")[i] <= 0) continue;
        ++cells;
        if (drawn[i] == 0.f) {
          ++zeros;
          continue;
        }
        // Not 0: the centre 0.28 / 0.7 = 0.4, + 2 scales, on the grid.
        const double want = std::round((mean[i] / 0.7 + 2.0 * scale[i]) * 100) / 100;
        ASSERT_NEAR(drawn[i], want, 1e-6) << file << " cell " << i;
      }
    }
    EXPECT_NEAR(static_cast<double>(zeros) / cells, 0.3, 0.02) << file << " over " << cells << " cells";
  }
}
