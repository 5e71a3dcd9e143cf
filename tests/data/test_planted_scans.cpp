// The planted-effect generator of the intensity campaign (data/planted_scans.h): parameters in
// their ranges, the same draw for the same seed, the effect really in the target, the score.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <set>

#include "common/error.h"
#include "data/import.h"
#include "data/planted_scans.h"
#include "pgm/materials.h"
#include "pgm/projection.h"

namespace lidarsim::data {
namespace {

// A small scan on a 16 x 64 grid: a ring of walls at 4-40 m, classes by column blocks.
Dataset synthetic_geometry() {
  const pgm::BeamLayout layout = pgm::BeamLayout::uniform(16, 10, -20, 64);
  std::vector<pgm::Point> points;
  const int classes[4] = {pgm::cls::road, pgm::cls::building, pgm::cls::vegetation, pgm::cls::car};
  for (int r = 0; r < layout.rows(); ++r)
    for (int c = 0; c < layout.columns; ++c) {
      const double az = layout.azimuth_of_column(c), el = layout.elevations_rad[r];
      const double range = 4 + 36.0 * ((c * 7 + r * 3) % 64) / 63.0;
      pgm::Point p;
      p.x = static_cast<float>(range * std::cos(el) * std::cos(az));
      p.y = static_cast<float>(range * std::cos(el) * std::sin(az));
      p.z = static_cast<float>(range * std::sin(el));
      p.class_id = classes[(c / 16) % 4];
      p.material_id = pgm::default_material(p.class_id);
      p.ring = r;
      points.push_back(p);
    }
  pgm::ProjectOptions po;
  po.row_mode = pgm::RowMode::Ring;
  po.extra_channels = {"elevation", "azimuth", "height", "incidence", "depth_discontinuity"};
  Dataset d;
  d.layout = layout;
  d.channels = {"range", "class", "material"};
  d.channels.insert(d.channels.end(), po.extra_channels.begin(), po.extra_channels.end());
  d.append(pgm::project(points, layout, po).pgm, "synthetic/0/000000", "ring", {"synthetic", "0", "000000"});
  return d;
}

TEST(PlantedScans, ParametersInTheirRanges) {
  const Dataset g = synthetic_geometry();
  for (std::uint64_t seed = 0; seed < 200; ++seed) {
    for (PlantedScanFamily f : all_planted_families()) {
      const PlantedScanDraw d = draw_planted(f, seed, g);
      const PlantedScanEffect& e = d.effect;
      for (double a : d.base.albedo) EXPECT_TRUE(a >= 0.15 && a <= 0.6) << a;
      EXPECT_TRUE(d.base.attenuation_m >= 60 && d.base.attenuation_m <= 150);
      const auto& p = e.parameters;
      switch (f) {
        case PlantedScanFamily::BeamGain: {
          const double s = p["spread"];
          EXPECT_TRUE(s >= 0.1 && s <= 0.5) << s;
          ASSERT_EQ(static_cast<int>(e.row_gain.size()), g.rows());
          for (double x : e.row_gain) EXPECT_LE(std::abs(x - 1), s + 1e-12);
          break;
        }
        case PlantedScanFamily::BadLasers: {
          EXPECT_TRUE(p["bad_lasers"].size() >= 2 && p["bad_lasers"].size() <= 10) << p.dump();
          int bad = 0;
          for (double x : e.row_gain)
            if (x != 1.0) {
              ++bad;
              EXPECT_TRUE(x >= 0.3 && x <= 0.8) << x;
            }
          EXPECT_EQ(bad, static_cast<int>(p["bad_lasers"].size()));  // distinct lasers
          break;
        }
        case PlantedScanFamily::AzimuthWindow:
          EXPECT_TRUE(e.azimuth_width_deg >= 20 && e.azimuth_width_deg <= 120);
          EXPECT_TRUE(e.azimuth_start_deg >= 0 && e.azimuth_start_deg < 360);
          EXPECT_TRUE((e.gain >= 0.4 && e.gain <= 0.8) || (e.gain >= 1.25 && e.gain <= 2)) << e.gain;
          break;
        case PlantedScanFamily::RangeFalloff: {
          const int size = e.row_last - e.row_first + 1;
          EXPECT_TRUE(size >= g.rows() / 4 && size <= g.rows() / 2 && e.row_first >= 0 && e.row_last < g.rows());
          EXPECT_TRUE(std::abs(e.exponent) >= 0.2 && std::abs(e.exponent) <= 0.6) << e.exponent;
          break;
        }
        case PlantedScanFamily::IncidenceFalloff: EXPECT_TRUE(e.exponent >= 0.3 && e.exponent <= 1.2); break;
        case PlantedScanFamily::ClassGain:
          EXPECT_TRUE((e.gain >= 0.5 && e.gain <= 0.8) || (e.gain >= 1.25 && e.gain <= 1.6)) << e.gain;
          EXPECT_TRUE(e.class_id == pgm::cls::road || e.class_id == pgm::cls::building ||
                      e.class_id == pgm::cls::vegetation || e.class_id == pgm::cls::car);
          break;
        case PlantedScanFamily::Control: EXPECT_TRUE(e.feature.empty()); break;
      }
    }
  }
}

TEST(PlantedScans, DeterministicBySeed) {
  const Dataset g = synthetic_geometry();
  for (PlantedScanFamily f : all_planted_families()) {
    const PlantedScanDraw a = draw_planted(f, 42, g), b = draw_planted(f, 42, g), c = draw_planted(f, 43, g);
    EXPECT_EQ(a.to_json(), b.to_json()) << to_string(f);
    EXPECT_NE(a.to_json(), c.to_json()) << to_string(f);
    const Dataset pa = plant(g, a), pb = plant(g, b), pc = plant(g, c);
    const std::size_t n = pa.target.shape().numel();
    EXPECT_EQ(0, std::memcmp(pa.target.data(), pb.target.data(), n * sizeof(float))) << to_string(f);
    EXPECT_NE(0, std::memcmp(pa.target.data(), pc.target.data(), n * sizeof(float))) << to_string(f);
  }
}

// The base is drawn before the effect from the same stream: one seed gives one base for every
// family, so planted / control is the effect's gain, cell by cell.
TEST(PlantedScans, EffectIsInTheTarget) {
  const Dataset g = synthetic_geometry();
  const int W = g.cols();
  const Dataset control = plant(g, draw_planted(PlantedScanFamily::Control, 7, g), false);
  const PlantedScanDraw beam = draw_planted(PlantedScanFamily::BeamGain, 7, g);
  const Dataset gained = plant(g, beam, false);
  for (int r = 0; r < g.rows(); ++r) {
    double ratio = 0;
    for (int c = 0; c < W; ++c) ratio += gained.target.data()[r * W + c] / control.target.data()[r * W + c];
    EXPECT_NEAR(ratio / W, beam.effect.row_gain[r], 1e-5) << "row " << r;
  }
  const PlantedScanDraw window = draw_planted(PlantedScanFamily::AzimuthWindow, 7, g);
  const Dataset windowed = plant(g, window, false);
  const int iaz = g.channel_index("azimuth");
  int inside = 0;
  for (int k = 0; k < g.rows() * W; ++k) {
    const double deg = std::fmod(g.pgm.data()[iaz * g.rows() * W + k] * 180 / M_PI + 720, 360);
    const bool in = std::fmod(deg - window.effect.azimuth_start_deg + 720, 360) < window.effect.azimuth_width_deg;
    inside += in;
    EXPECT_NEAR(windowed.target.data()[k] / control.target.data()[k], in ? window.effect.gain : 1.0, 1e-5);
  }
  EXPECT_GT(inside, 0);
  // The noise has the draw's sigma.
  const Dataset noisy = plant(g, draw_planted(PlantedScanFamily::Control, 7, g, 0.05));
  double sq = 0;
  for (int k = 0; k < g.rows() * W; ++k) sq += std::pow(noisy.target.data()[k] - control.target.data()[k], 2);
  EXPECT_NEAR(std::sqrt(sq / (g.rows() * W)), 0.05, 0.005);
}

TEST(PlantedScans, ScoreUsesTheExcessOverTheNoise) {
  const Dataset g = synthetic_geometry();
  const PlantedScanDraw d = draw_planted(PlantedScanFamily::BeamGain, 1, g, 0.03);
  const nlohmann::json hit = {{"added_effect", "beam_row"}, {"rmse_before", 0.05}, {"rmse_after", 0.032}};
  PlantedScore s = score_planted(d, hit);
  EXPECT_NEAR(s.excess_before, 0.04, 1e-12);
  EXPECT_NEAR(s.excess_after, std::sqrt(0.032 * 0.032 - 0.0009), 1e-12);
  EXPECT_TRUE(s.named && s.cut && s.hit && !s.false_add);
  // Named, but the error barely fell: not a hit (0.045 vs 0.05 is 0.84 x in excess).
  s = score_planted(d, {{"added_effect", "beam_row"}, {"rmse_before", 0.05}, {"rmse_after", 0.045}});
  EXPECT_TRUE(s.named && !s.cut && !s.hit);
  s = score_planted(d, {{"added_effect", "height"}, {"rmse_before", 0.05}, {"rmse_after", 0.031}});
  EXPECT_TRUE(!s.named && !s.hit && s.false_add);
  // Below the noise the excess is 0, not NaN.
  s = score_planted(d, {{"added_effect", nullptr}, {"rmse_before", 0.02}, {"rmse_after", 0.02}});
  EXPECT_EQ(s.excess_before, 0.0);
  const PlantedScanDraw control = draw_planted(PlantedScanFamily::Control, 1, g);
  EXPECT_TRUE(score_planted(control, {{"added_effect", nullptr}, {"rmse_before", 0.03}, {"rmse_after", 0.03}}).hit);
  EXPECT_FALSE(score_planted(control, {{"added_effect", "azimuth"}, {"rmse_before", 0.03}, {"rmse_after", 0.03}}).hit);
  EXPECT_THROW(score_planted(d, {{"added_effect", nullptr}}), Error);
}

TEST(PlantedScans, UnknownFamilyAndMissingChannelAreClearErrors) {
  try {
    planted_scan_family_from_string("beam");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("beam_gain"), std::string::npos) << e.what();
  }
  Dataset g = synthetic_geometry();
  g.channels[g.channel_index("incidence")] = "renamed";
  try {
    plant(g, draw_planted(PlantedScanFamily::Control, 1, g));
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("incidence"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace lidarsim::data
