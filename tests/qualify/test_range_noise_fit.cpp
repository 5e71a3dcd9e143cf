// The range-noise fit on synthetic scans whose noise is known: a road seen at grazing incidence and
// a wall seen obliquely, every range scattered ALONG ITS BEAM by a known sigma. The fit must give
// that sigma back (a fit that measured the perpendicular distance to the surface would read
// sigma x cos(incidence), 0.1-0.3 sigma on the road), and nothing on exact ranges.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <numbers>
#include <random>

#include "pgm/materials.h"
#include "qualify/range_noise_fit.h"
#include "sensor/frames.h"
#include "sensor/pcl_generator.h"
#include "sensor/range_noise.h"

using namespace lidarsim::qualify;
namespace pgm = lidarsim::pgm;

namespace {

constexpr double kDeg = std::numbers::pi / 180;

struct SyntheticScan {
  std::vector<pgm::Point> points;
  std::vector<int> rows;
  std::vector<float> incidence;  // true, rad
};

// Sensor 1.73 m above a flat road; a building wall along y = 12 m (left), seen from ~0 to ~85 deg
// incidence along the row. 48 rows from +2 to -22 deg, 2000 points per row (0.18 deg, like an
// HDL-64E at 10 Hz). sigma(r) = sqrt(a^2 + (b r)^2) along each beam.
SyntheticScan scene(double a, double b, std::uint64_t seed) {
  SyntheticScan s;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  const int rows = 48, cols = 2000;
  const double h = 1.73, wall_y = 12;
  for (int r = 0; r < rows; ++r) {
    const double el = (2 - 24.0 * r / (rows - 1)) * kDeg;
    for (int c = 0; c < cols; ++c) {
      const double az = -std::numbers::pi + 2 * std::numbers::pi * (c + 0.5) / cols;
      const double ux = std::cos(el) * std::cos(az), uy = std::cos(el) * std::sin(az), uz = std::sin(el);
      double t = 1e9, inc = 0;
      int cls = -1;
      if (uz < 0) t = -h / uz, inc = std::acos(-uz), cls = pgm::cls::road;
      if (uy > 0 && wall_y / uy < t) t = wall_y / uy, inc = std::acos(uy), cls = pgm::cls::building;
      if (cls < 0 || t > 100) continue;
      const double noisy = t + std::hypot(a, b * t) * normal(rng);
      pgm::Point p;
      p.x = static_cast<float>(noisy * ux), p.y = static_cast<float>(noisy * uy), p.z = static_cast<float>(noisy * uz);
      p.class_id = cls;
      p.intensity = 0.3f;
      s.points.push_back(p);
      s.rows.push_back(r);
      s.incidence.push_back(static_cast<float>(inc));
    }
  }
  return s;
}

std::vector<float> residuals_of(const std::vector<RangeResidual>& rs, int cls = -1) {
  std::vector<float> v;
  for (const auto& r : rs)
    if (cls < 0 || r.class_id == cls) v.push_back(r.residual);
  return v;
}

}  // namespace

TEST(RangeNoiseFit, RecoversTheInjectedSigmaOnRoadAndWall) {
  for (int k : {1, 2, 3})
  for (double sigma : {0.02, 0.05}) {
    const auto s = scene(sigma, 0, 1);
    RangeFitOptions o;
    o.half_window = k;
    const auto rs = range_residuals(s.points, s.rows, s.incidence, o);
    const auto road = residuals_of(rs, pgm::cls::road), wall = residuals_of(rs, pgm::cls::building);
    ASSERT_GT(road.size(), 20000u);
    ASSERT_GT(wall.size(), 5000u);
    // MAD of n >= 5000 Gaussian residuals: ~1.2 % standard error; 6 % is five of them.
    EXPECT_NEAR(robust_sigma(road), sigma, 0.06 * sigma) << "sigma " << sigma << ", half-window " << k;
    EXPECT_NEAR(robust_sigma(wall), sigma, 0.06 * sigma) << "sigma " << sigma << ", half-window " << k;
  }
}

TEST(RangeNoiseFit, MeasuresAlongTheBeamAtEveryIncidence) {
  // Grazing road (incidence 68-88 deg) and the wall from head-on to grazing: every incidence bin
  // reads the injected sigma; a perpendicular distance would fall as cos(incidence).
  const double sigma = 0.03;
  const auto s = scene(sigma, 0, 2);
  const auto rs = range_residuals(s.points, s.rows, s.incidence);
  std::vector<double> edges;
  for (int d = 0; d <= 90; d += 15) edges.push_back(d * kDeg);
  const auto bins = spread_by(rs, [](const RangeResidual& r) { return r.incidence; }, edges, 500);
  ASSERT_GE(bins.size(), 5u);
  for (const auto& b : bins) EXPECT_NEAR(b.sigma, sigma, 0.1 * sigma) << "incidence " << b.lo / kDeg << "-" << b.hi / kDeg;
}

TEST(RangeNoiseFit, ExactRangesGiveNoSpread) {
  // The fit's own error on a noiseless scene (the beam cone's curvature, float rounding) must be
  // far below any real sensor's noise: the spread it reports is the data's, not the method's.
  const auto s = scene(0, 0, 3);
  const auto rs = range_residuals(s.points, s.rows, s.incidence);
  ASSERT_GT(rs.size(), 20000u);
  EXPECT_LT(robust_sigma(residuals_of(rs)), 0.001);
}

TEST(RangeNoiseFit, RangeDependenceIsFittedPerBin) {
  // sigma grows with range: a = 1 cm, b = 1 mm per m (3.2 cm at 30 m). Per 5 m bin and the
  // fitted (a, b) follow it.
  const double a = 0.01, b = 0.001;
  const auto s = scene(a, b, 4);
  const auto rs = range_residuals(s.points, s.rows, s.incidence);
  std::vector<double> edges;
  for (int e = 0; e <= 60; e += 5) edges.push_back(e);
  const auto bins = spread_by(rs, [](const RangeResidual& r) { return r.range; }, edges, 500);
  ASSERT_GE(bins.size(), 5u);
  for (const auto& bin : bins) {
    // sigma varies inside a bin: the injected spread at the bin's mean range, within 8 %.
    const double expected = std::hypot(a, b * bin.mean);
    EXPECT_NEAR(bin.sigma, expected, 0.08 * expected) << "range " << bin.lo;
  }
  const auto fit = fit_sigma_of_range(bins);
  EXPECT_NEAR(fit.a, a, 0.2 * a);
  EXPECT_NEAR(fit.b, b, 0.1 * b);
}

TEST(RangeNoiseFit, EdgesAndOtherClassesAreLeftOut) {
  // A wall's neighbourhoods that reach onto the road (mixed classes) are not fitted, and a class
  // outside the planar set (vegetation) gives no residuals at all.
  auto s = scene(0.02, 0, 5);
  for (auto& p : s.points)
    if (p.class_id == pgm::cls::building) p.class_id = pgm::cls::vegetation;
  const auto rs = range_residuals(s.points, s.rows, s.incidence);
  EXPECT_TRUE(residuals_of(rs, pgm::cls::vegetation).empty());
  ASSERT_FALSE(rs.empty());
  for (const auto& r : rs) EXPECT_EQ(r.class_id, pgm::cls::road);
}

TEST(RangeNoiseFit, SimulatedScanReadsBackTheShippedModel) {
  // The loop closed: the PCL generator applies the shipped HDL-64E model to a road, and the same
  // fit that made the model reads its table back from the simulated scan, bin by bin.
  const auto model = std::make_shared<const lidarsim::sensor::RangeNoiseModel>(lidarsim::sensor::load_range_noise_model(
      std::string(LIDARSIM_SOURCE_DIR) + "/data/models/range_noise_hdl64e.json"));
  lidarsim::sensor::PclConfig cfg;
  cfg.range_noise = model;
  cfg.range_noise_seed = 3;
  const auto layout = pgm::BeamLayout::hdl64e();
  lidarsim::sensor::PclGenerator gen(layout, lidarsim::sensor::make_pose({0, 0, 1.73}, 0, 0, 0), cfg);
  std::vector<pgm::Point> points;
  std::vector<int> rows;
  for (std::uint64_t frame = 0; frame < 4; ++frame) {
    auto map = gen.make_map({"x", "y", "z"});
    gen.set_frame(frame);
    gen.generate({}, {}, map);
    const float *x = map.channel("x"), *y = map.channel("y"), *z = map.channel("z"), *mask = map.channel("mask");
    std::vector<pgm::Point> frame_points;
    for (std::size_t i = 0; i < map.cells(); ++i) {
      if (!(mask[i] > 0)) continue;
      pgm::Point p;
      p.x = x[i], p.y = y[i], p.z = z[i];
      p.class_id = pgm::cls::road;
      points.push_back(p);
      // Frames apart: each frame's rows are their own (a frame's row r is row r + 64 frame).
      rows.push_back(static_cast<int>(i / layout.columns + frame * layout.rows()));
    }
  }
  const auto rs = range_residuals(points, rows, {});
  std::vector<double> edges;
  for (int e = 0; e <= 50; e += 5) edges.push_back(e);
  const auto bins = spread_by(rs, [](const RangeResidual& r) { return r.range; }, edges, 1000);
  ASSERT_GE(bins.size(), 6u);
  for (const auto& b : bins) {
    // sigma changes inside a bin: compare with the model's rms over the bin's residuals.
    double s2 = 0;
    std::size_t n = 0;
    for (const auto& r : rs)
      if (r.range >= b.lo && r.range < b.hi) s2 += model->sigma(r.range) * model->sigma(r.range), ++n;
    const double expected = std::sqrt(s2 / n);
    EXPECT_NEAR(b.sigma, expected, 0.08 * expected) << "range " << b.lo << "-" << b.hi << " (n " << b.n << ")";
  }
}
