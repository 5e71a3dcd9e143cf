// The closed loop on range noise (qualify/range_noise/range_noise_loop.h) on synthetic residuals
// whose truth is known, the guard bands of its azimuth folds, and the model's spread terms
// (sensor/range_noise.h, format version 2). Milliseconds to a second.
#include <gtest/gtest.h>

#include <cmath>

#include "common/error.h"
#include "pgm/materials.h"
#include "qualify/range_noise/range_noise_loop.h"
#include "qualify/similarity.h"
#include "sensor/range_noise.h"

using namespace lidarsim;

namespace {

// Residuals of `scans` scans, 64 lasers x 600 azimuths: range grows down the lasers (4-60 m),
// classes road / sidewalk / building by azimuth, spread 0.8 cm + 0.3 mm/m, times `factor(row,
// class)`; Gaussian.
template <class Factor>
std::vector<qualify::LoopResidual> synthetic(int scans, std::uint64_t seed, Factor&& factor) {
  qualify::SplitMix rng(seed);
  std::vector<qualify::LoopResidual> out;
  for (int s = 0; s < scans; ++s)
    for (int row = 0; row < 64; ++row)
      for (int k = 0; k < 600; ++k) {
        qualify::LoopResidual x;
        x.scan = s;
        x.r.row = row;
        x.r.azimuth_deg = static_cast<float>((k + 0.5) * 0.6);
        x.r.range = static_cast<float>(60 - 56 * row / 63.0 + rng.uniform());
        x.r.class_id = k % 3 == 0 ? pgm::cls::road : k % 3 == 1 ? pgm::cls::sidewalk : pgm::cls::building;
        x.r.material = pgm::default_material(x.r.class_id);
        x.r.incidence = static_cast<float>(0.3 + 1.2 * rng.uniform());
        x.r.intensity = static_cast<float>(rng.uniform());
        const double sigma = std::hypot(0.008, 0.0003 * x.r.range) * factor(row, x.r.class_id);
        x.r.residual = static_cast<float>(sigma * rng.normal());
        out.push_back(x);
      }
  return out;
}

}  // namespace

TEST(RangeNoiseLoop, NamesTwoNoisyLasersAndRecoversTheirFactor) {
  const auto reference = synthetic(2, 1, [](int, int) { return 1.0; });
  const auto target = synthetic(2, 2, [](int row, int) { return row == 12 || row == 40 ? 2.5 : 1.0; });
  const auto r = qualify::loop_range_noise(target, reference);
  ASSERT_EQ(r.added_feature, "laser");
  EXPECT_LT(r.error_after, 0.99 * r.error_before);
  const auto& t = r.candidates[0].term;
  ASSERT_EQ(t.feature, "laser");
  EXPECT_NEAR(t.factor[12], 2.5, 0.25);
  EXPECT_NEAR(t.factor[40], 2.5, 0.25);
  EXPECT_NEAR(t.factor[30], 1.0, 0.08);
  // The written model carries the term: the spread on laser 12 is 2.5 x that on laser 30 at one range.
  ASSERT_EQ(r.model.terms.size(), 1u);
  sensor::RangeNoiseFeatures a, b;
  a.range_m = b.range_m = 20, a.row = 12, b.row = 30;
  EXPECT_NEAR(r.model.sigma_at(a) / r.model.sigma_at(b), 2.5, 0.3);
  // Every candidate is listed with its decision and a reason.
  for (const auto& c : r.candidates) EXPECT_FALSE(c.reason.empty()) << c.feature << " " << to_string(c.form);
}

TEST(RangeNoiseLoop, NamesANoisierClassAndASpreadGrowingWithRange) {
  const auto reference = synthetic(2, 3, [](int, int) { return 1.0; });
  const auto noisy_class = synthetic(2, 4, [](int, int c) { return c == pgm::cls::sidewalk ? 1.8 : 1.0; });
  const auto rc = qualify::loop_range_noise(noisy_class, reference);
  EXPECT_TRUE(rc.added_feature == "class" || rc.added_feature == "material") << rc.added_feature;
  // Extra sigma 1 mm per metre: the far lasers (low rows) get noisier.
  const auto growing = synthetic(2, 5, [](int row, int) {
    const double r = 60 - 56 * row / 63.0;
    return std::hypot(std::hypot(0.008, 0.0003 * r), 0.001 * r) / std::hypot(0.008, 0.0003 * r);
  });
  const auto rr = qualify::loop_range_noise(growing, reference);
  // Range and laser are the same thing in this geometry; either names the growth.
  EXPECT_TRUE(rr.added_feature == "range" || rr.added_feature == "laser") << rr.added_feature;
}

// min_gain 0: only the selection-aware bound keeps chance gains out (without it, adding any
// positive held-out cut, these controls add a table).
TEST(RangeNoiseLoop, ControlAddsNothingOnTheBoundAlone) {
  for (std::uint64_t seed : {6, 7, 8}) {
    const auto reference = synthetic(2, seed, [](int, int) { return 1.0; });
    const auto target = synthetic(2, seed + 100, [](int, int) { return 1.0; });
    qualify::RangeLoopOptions o;
    o.min_gain = 0;
    o.rotation_deg = static_cast<double>(seed);
    const auto r = qualify::loop_range_noise(target, reference, o);
    EXPECT_EQ(r.added_feature, "") << "seed " << seed << ": " << (r.candidates.empty() ? "" : r.candidates[0].reason);
    EXPECT_EQ(r.error_after, r.error_before);
  }
}

TEST(RangeNoiseLoop, GuardBandsLeaveBoundaryResidualsUnscored) {
  auto target = synthetic(1, 9, [](int, int) { return 1.0; });
  qualify::RangeLoopOptions o;  // 64 sectors of 5.625 deg, guard 0.5 deg
  const auto r = qualify::loop_range_noise(target, target, o);
  long long guarded = 0, scored = 0;
  for (std::size_t i = 0; i < target.size(); ++i) {
    const double u = std::fmod(target[i].r.azimuth_deg, 360.0 / 64);
    const bool near_edge = u < 0.5 || u > 360.0 / 64 - 0.5;
    EXPECT_EQ(r.fold[i] < 0, near_edge) << "azimuth " << target[i].r.azimuth_deg;
    EXPECT_EQ(std::isfinite(r.b_before[i]), !near_edge);
    guarded += near_edge, scored += !near_edge;
    if (!near_edge) {
      EXPECT_EQ(r.fold[i], static_cast<int>(target[i].r.azimuth_deg / (360.0 / 64)) % 4);
    }
  }
  EXPECT_EQ(r.scored, scored);
  EXPECT_GT(guarded, 0);
}

TEST(RangeNoiseModelTerms, VersionTwoRoundTripsAndOlderFilesStillLoad) {
  sensor::RangeNoiseModel m;
  m.sensor = "hdl64e", m.a = 0.008, m.b = 0.0003;
  m.table_range_m = {5, 15}, m.table_sigma_m = {0.009, 0.010};
  const std::string v1 = sensor::range_noise_model_json(m);
  EXPECT_NE(v1.find("\"version\": 1"), std::string::npos);
  m.terms.push_back({"laser", 1, std::vector<double>(64, 1.0), "test"});
  m.terms[0].factor[5] = 3;
  m.terms.push_back({"azimuth", 10, std::vector<double>(36, 1.0), ""});
  m.terms[1].factor[35] = 2;
  const std::string v2 = sensor::range_noise_model_json(m);
  EXPECT_NE(v2.find("\"version\": 2"), std::string::npos);
  const auto back = sensor::parse_range_noise_model(v2, "m.json");
  ASSERT_EQ(back.terms.size(), 2u);
  sensor::RangeNoiseFeatures f;
  f.range_m = 10, f.row = 5, f.azimuth_deg = 355;
  EXPECT_NEAR(back.sigma_at(f), 6 * back.sigma(10), 1e-12);
  f.azimuth_deg = -5 + 360 - 360;  // wraps to the last bin as well
  EXPECT_NEAR(back.sigma_at(f), 6 * back.sigma(10), 1e-12);
  f.row = 6, f.azimuth_deg = 10;
  EXPECT_NEAR(back.sigma_at(f), back.sigma(10), 1e-12);
  EXPECT_EQ(sensor::parse_range_noise_model(v1, "m.json").terms.size(), 0u);
}

TEST(RangeNoiseModelTerms, BadTermsNameTheField) {
  auto error_of = [](const std::string& text) {
    try {
      sensor::parse_range_noise_model(text, "m.json");
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string head = R"({"format": "lidarsim-range-noise", "sigma_m": {"a": 0.01, "b": 0.0003}, )";
  EXPECT_NE(error_of(head + R"("version": 1, "terms": []})").find("terms"), std::string::npos);
  EXPECT_NE(error_of(head + R"("version": 3})").find("version"), std::string::npos);
  EXPECT_NE(error_of(head + R"("version": 2, "terms": [{"feature": "colour", "width": 1, "factor": [1]}]})")
                .find("terms[0].feature"),
            std::string::npos);
  EXPECT_NE(error_of(head + R"("version": 2, "terms": [{"feature": "laser", "width": 1, "factor": [0]}]})")
                .find("terms[0].factor"),
            std::string::npos);
  EXPECT_NE(error_of(head + R"("version": 2, "terms": [{"feature": "laser", "width": 0, "factor": [1]}]})")
                .find("terms[0].width"),
            std::string::npos);
}

TEST(RangeNoiseModelTerms, SimulationAppliesALaserTermAndNamesAMissingChannel) {
  pgm::BeamLayout layout = pgm::BeamLayout::hdl64e();
  pgm::PolarGridMap map(layout, {"range", "mask", "class"});
  for (int row = 0; row < map.rows(); ++row)
    for (int c = 0; c < map.cols(); ++c) {
      map.at(map.channel_index("range"), row, c) = 20;
      map.at(map.channel_index("mask"), row, c) = 1;
    }
  sensor::RangeNoiseModel m;
  m.a = 0.01;
  m.terms.push_back({"laser", 1, std::vector<double>(64, 1.0), ""});
  m.terms[0].factor[7] = 4;
  sensor::apply_range_noise(m, 1, 0, map);
  auto spread = [&](int row) {
    double s = 0;
    for (int c = 0; c < map.cols(); ++c) s += std::pow(map.at(map.channel_index("range"), row, c) - 20.0, 2);
    return std::sqrt(s / map.cols());
  };
  EXPECT_NEAR(spread(7) / spread(8), 4, 0.5);
  EXPECT_NEAR(spread(8), 0.01, 0.001);
  m.terms.push_back({"intensity", 0.1, std::vector<double>(10, 1.0), ""});
  try {
    sensor::apply_range_noise(m, 1, 0, map);
    FAIL() << "no error for a term without its channel";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("intensity"), std::string::npos) << e.what();
  }
}
