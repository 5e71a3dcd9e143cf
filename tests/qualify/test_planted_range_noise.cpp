// The planted range-noise effects of the loop's campaign (qualify/range_noise/range_noise_plant.cpp):
// each family acts where it says and nowhere else, its parameters stay in their documented ranges,
// and a plant moves points along their beams only.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/error.h"
#include "qualify/range_noise/range_noise_loop.h"

namespace lidarsim::qualify {
namespace {

PlantedPoint at_azimuth(double deg) {
  PlantedPoint p;
  p.azimuth_deg = deg;
  return p;
}

std::vector<double> uniform_quantiles() {  // intensities spread evenly over 0..1
  std::vector<double> q;
  for (int k = 0; k <= 100; ++k) q.push_back(k / 100.0);
  return q;
}

TEST(PlantedRangeNoise, AzimuthWindowWrapsAroundTheCircle) {
  PlantedRangeEffect e;
  e.family = PlantedRangeFamily::AzimuthNoise;
  e.window_start_deg = 350, e.window_width_deg = 30, e.sigma = 0.02;
  EXPECT_EQ(e.extra_sigma(at_azimuth(355)), 0.02);
  EXPECT_EQ(e.extra_sigma(at_azimuth(10)), 0.02);
  EXPECT_EQ(e.extra_sigma(at_azimuth(19.9)), 0.02);
  EXPECT_EQ(e.extra_sigma(at_azimuth(20.1)), 0.0);
  EXPECT_EQ(e.extra_sigma(at_azimuth(349)), 0.0);
  EXPECT_EQ(e.extra_sigma(at_azimuth(180)), 0.0);
}

TEST(PlantedRangeNoise, IncidenceGrowsWithItsTangentUpToTheCapAndNeedsAnEstimate) {
  PlantedRangeEffect e;
  e.family = PlantedRangeFamily::IncidenceNoise;
  e.per_tan = 0.003;
  PlantedPoint p;
  EXPECT_EQ(e.extra_sigma(p), 0.0);  // incidence not estimated
  p.incidence_rad = M_PI / 4;
  EXPECT_NEAR(e.extra_sigma(p), 0.003, 1e-12);
  p.incidence_rad = 89.0 * M_PI / 180.0;
  EXPECT_NEAR(e.extra_sigma(p), 0.003 * std::tan(80.0 * M_PI / 180.0), 1e-12);
}

TEST(PlantedRangeNoise, IntensityActsOnTheWeakReturnsOnly) {
  PlantedRangeEffect e;
  e.family = PlantedRangeFamily::IntensityNoise;
  e.intensity_below = 0.2, e.sigma = 0.015;
  PlantedPoint p;
  p.intensity = 0.1;
  EXPECT_EQ(e.extra_sigma(p), 0.015);
  p.intensity = 0.2;
  EXPECT_EQ(e.extra_sigma(p), 0.0);
}

TEST(PlantedRangeNoise, DrawsStayInTheirDocumentedRanges) {
  const std::vector<double> rows(64, 1.0 / 64), classes(30, 0.1), q = uniform_quantiles();
  for (std::uint64_t seed = 1; seed <= 50; ++seed) {
    const auto a = draw_planted_range(PlantedRangeFamily::AzimuthNoise, seed, rows, classes, q);
    EXPECT_TRUE(a.window_width_deg >= 20 && a.window_width_deg <= 120) << a.parameters.dump();
    EXPECT_TRUE(a.window_start_deg >= 0 && a.window_start_deg < 360) << a.parameters.dump();
    EXPECT_TRUE(a.sigma >= 0.01 && a.sigma <= 0.03) << a.parameters.dump();
    EXPECT_EQ(a.accepted, std::vector<std::string>{"azimuth"});
    const auto i = draw_planted_range(PlantedRangeFamily::IncidenceNoise, seed, rows, classes, q);
    EXPECT_TRUE(i.per_tan >= 0.002 && i.per_tan <= 0.005) << i.parameters.dump();
    const auto w = draw_planted_range(PlantedRangeFamily::IntensityNoise, seed, rows, classes, q);
    EXPECT_TRUE(w.intensity_below >= 0.1 && w.intensity_below <= 0.4) << w.parameters.dump();
    EXPECT_EQ(w.accepted, std::vector<std::string>{"intensity"});
  }
  EXPECT_THROW(draw_planted_range(PlantedRangeFamily::IntensityNoise, 1, rows, classes, {}), Error);
  EXPECT_THROW(draw_planted_range(PlantedRangeFamily::IntensityNoise, 1, rows, classes, std::vector<double>(101, 0.3)),
               Error);
}

// A ring of points on a cylinder 10 m away: the window's points move along their beams, the others
// keep their bits.
TEST(PlantedRangeNoise, AzimuthPlantMovesOnlyTheWindowsPointsAndAlongTheirBeams) {
  const pgm::BeamLayout layout = pgm::BeamLayout::hdl64e();
  std::vector<pgm::Point> points;
  for (int k = 0; k < 720; ++k) {
    const double az = (k + 0.5) * M_PI / 360.0;
    pgm::Point p;
    p.x = static_cast<float>(10 * std::cos(az)), p.y = static_cast<float>(10 * std::sin(az)), p.z = -1.0f;
    points.push_back(p);
  }
  PlantedRangeEffect e;
  e.family = PlantedRangeFamily::AzimuthNoise;
  e.window_start_deg = 330, e.window_width_deg = 60, e.sigma = 0.03;
  const auto planted = plant_range_noise(points, layout, e, 7, 0);
  int moved = 0;
  for (std::size_t k = 0; k < points.size(); ++k) {
    const double az = std::fmod(std::atan2(points[k].y, points[k].x) * 180 / M_PI + 360, 360);
    const bool inside = az >= 330 || az < 30;
    if (!inside) {
      EXPECT_EQ(planted[k].x, points[k].x) << az;
      EXPECT_EQ(planted[k].y, points[k].y) << az;
      continue;
    }
    moved += planted[k].x != points[k].x;
    const double ratio_x = planted[k].x / points[k].x, ratio_z = planted[k].z / points[k].z;
    EXPECT_NEAR(ratio_x, ratio_z, 1e-5) << az;  // along the beam
  }
  EXPECT_GT(moved, 100);
}

}  // namespace
}  // namespace lidarsim::qualify
