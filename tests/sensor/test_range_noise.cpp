// Range noise applied by the PCL generator: off by default, deterministic in (seed, frame, cell)
// whatever the thread count, its spread the model's, and every point kept on its beam.
#include <gtest/gtest.h>

#include <omp.h>

#include <cmath>
#include <memory>
#include <numbers>
#include <string>

#include "common/error.h"
#include "sensor/frames.h"
#include "sensor/pcl_generator.h"
#include "sensor/range_noise.h"

using namespace lidarsim::sensor;
namespace pgm = lidarsim::pgm;

namespace {

// 32 rows looking down at the road from 1.8 m (-2 .. -25 deg), 1024 columns: ranges 4-50 m.
pgm::BeamLayout down_layout() { return pgm::BeamLayout::uniform(32, -2, -25, 1024); }

std::shared_ptr<const RangeNoiseModel> model(double a, double b) {
  auto m = std::make_shared<RangeNoiseModel>();
  m->a = a, m->b = b;
  return m;
}

pgm::PolarGridMap generate(const PclConfig& cfg, std::uint64_t frame) {
  PclGenerator gen(down_layout(), make_pose({0, 0, 1.8}, 0, 0, 0), cfg);
  auto map = gen.make_map({"x", "y", "z", "height", "incidence"});
  gen.set_frame(frame);
  gen.generate({}, {}, map);
  return map;
}

std::vector<float> channel(const pgm::PolarGridMap& m, const char* name) {
  return std::vector<float>(m.channel(name), m.channel(name) + m.cells());
}

}  // namespace

TEST(RangeNoise, ModelParsesAndBadFieldsAreNamed) {
  const auto m = parse_range_noise_model(
      R"({"format": "lidarsim-range-noise", "version": 1, "sensor": "hdl64e", "sigma_m": {"a": 0.01, "b": 0.0002}})", "m.json");
  EXPECT_EQ(m.sensor, "hdl64e");
  EXPECT_NEAR(m.sigma(0), 0.01, 1e-12);
  EXPECT_NEAR(m.sigma(50), std::sqrt(0.01 * 0.01 + 0.01 * 0.01), 1e-12);
  auto message = [](const std::string& text) {
    try {
      parse_range_noise_model(text, "m.json");
    } catch (const lidarsim::Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message(R"({"format": "x", "version": 1, "sigma_m": {"a": 0, "b": 0}})").find("m.json: format"), std::string::npos);
  EXPECT_NE(message(R"({"format": "lidarsim-range-noise", "version": 3, "sigma_m": {"a": 0, "b": 0}})").find("m.json: version"), std::string::npos);
  EXPECT_NE(message(R"({"format": "lidarsim-range-noise", "version": 1, "sigma_m": {"a": 0.01}})").find("m.json: sigma_m.b"), std::string::npos);
  // Centimetres written as metres: a spread of 2 m is refused.
  EXPECT_NE(message(R"({"format": "lidarsim-range-noise", "version": 1, "sigma_m": {"a": 2, "b": 0}})").find("m.json: sigma_m.a"), std::string::npos);
}

TEST(RangeNoise, TableIsFlatBelowLinearBetweenAndGrowsBeyond) {
  const auto m = parse_range_noise_model(
      R"({"format": "lidarsim-range-noise", "version": 1, "sigma_m": {"a": 0.01, "b": 0.001},
          "table": {"range_m": [5, 15, 25], "sigma_m": [0.01, 0.02, 0.04]}})", "m.json");
  EXPECT_NEAR(m.sigma(1), 0.01, 1e-12);
  EXPECT_NEAR(m.sigma(10), 0.015, 1e-12);
  EXPECT_NEAR(m.sigma(20), 0.03, 1e-12);
  // Beyond 25 m: 0.04 x smooth(50) / smooth(25).
  EXPECT_NEAR(m.sigma(50), 0.04 * std::hypot(0.01, 0.05) / std::hypot(0.01, 0.025), 1e-12);
  EXPECT_THROW(parse_range_noise_model(R"({"format": "lidarsim-range-noise", "version": 1, "sigma_m": {"a": 0, "b": 0},
      "table": {"range_m": [5, 4], "sigma_m": [0.01, 0.02]}})", "m.json"), lidarsim::Error);
}

TEST(RangeNoise, ShippedModelLoads) {
  const auto m = load_range_noise_model(std::string(LIDARSIM_SOURCE_DIR) + "/data/models/range_noise_hdl64e.json");
  EXPECT_EQ(m.sensor, "hdl64e");
  EXPECT_GT(m.sigma(20), 0.003);
  EXPECT_LT(m.sigma(20), 0.05);
}

TEST(RangeNoise, NormalIsStandardAndDependsOnlyOnItsKey) {
  double s = 0, s2 = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const double z = range_noise_normal(7, 3, i);
    s += z, s2 += z * z;
  }
  EXPECT_NEAR(s / n, 0, 0.01);
  EXPECT_NEAR(std::sqrt(s2 / n), 1, 0.01);
  EXPECT_EQ(range_noise_normal(7, 3, 11), range_noise_normal(7, 3, 11));
  EXPECT_NE(range_noise_normal(7, 3, 11), range_noise_normal(7, 4, 11));
  EXPECT_NE(range_noise_normal(7, 3, 11), range_noise_normal(8, 3, 11));
  EXPECT_NE(range_noise_normal(7, 3, 11), range_noise_normal(7, 3, 12));
}

TEST(RangeNoise, OffByDefaultLeavesTheExactRanges) {
  PclConfig cfg;
  EXPECT_EQ(cfg.range_noise, nullptr);
  const auto map = generate(cfg, 0);
  const auto& L = map.layout();
  const float* range = map.channel("range");
  for (int r = 0; r < L.rows(); ++r) {
    const double exact = 1.8 / std::sin(-L.elevations_rad[r]);
    for (int c = 0; c < L.columns; c += 97) EXPECT_NEAR(range[r * L.columns + c], exact, 1e-4 * exact);
  }
}

TEST(RangeNoise, GeneratorSpreadMatchesTheModelAlongTheBeam) {
  PclConfig exact_cfg, cfg;
  cfg.range_noise = model(0.02, 0.0005);
  cfg.range_noise_seed = 5;
  const auto exact = generate(exact_cfg, 0), noisy = generate(cfg, 0);
  const float* r0 = exact.channel("range");
  const float* r1 = noisy.channel("range");
  double s = 0, s2 = 0;
  int n = 0;
  for (std::size_t i = 0; i < exact.cells(); ++i) {
    if (!(exact.channel("mask")[i] > 0)) continue;
    const double z = (r1[i] - r0[i]) / cfg.range_noise->sigma(r0[i]);
    s += z, s2 += z * z, ++n;
    // x, y, z and height moved with the range: the point stays on its beam.
    const double k = r1[i] / r0[i];
    EXPECT_NEAR(noisy.channel("x")[i], exact.channel("x")[i] * k, 1e-4);
    EXPECT_NEAR(noisy.channel("z")[i], exact.channel("z")[i] * k, 1e-4);
    EXPECT_NEAR(noisy.channel("height")[i], exact.channel("height")[i] * k, 1e-4);
  }
  ASSERT_GT(n, 30000);
  EXPECT_NEAR(s / n, 0, 0.02);
  EXPECT_NEAR(std::sqrt(s2 / n - (s / n) * (s / n)), 1, 0.02);
  // The neighbourhood channels are estimated from the noisy ranges, as for a measured scan.
  EXPECT_NE(channel(noisy, "incidence"), channel(exact, "incidence"));
}

TEST(RangeNoise, DeterministicInSeedFrameAndCellWhateverTheThreads) {
  PclConfig cfg;
  cfg.range_noise = model(0.02, 0);
  cfg.range_noise_seed = 9;
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const auto one = channel(generate(cfg, 4), "range");
  omp_set_num_threads(3);
  const auto three = channel(generate(cfg, 4), "range");
  omp_set_num_threads(threads);
  EXPECT_EQ(one, three);
  EXPECT_NE(one, channel(generate(cfg, 5), "range"));  // another frame, other draws
  PclConfig other = cfg;
  other.range_noise_seed = 10;
  EXPECT_NE(one, channel(generate(other, 4), "range"));  // another seed, other draws
}
