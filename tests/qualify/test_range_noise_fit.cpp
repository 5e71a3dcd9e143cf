// The range-noise fit on synthetic scans whose noise is known: a road seen at grazing incidence and
// a wall seen obliquely, every range scattered ALONG ITS BEAM by a known sigma. The fit must give
// that sigma back (a fit that measured the perpendicular distance to the surface would read
// sigma x cos(incidence), 0.1-0.3 sigma on the road), and nothing on exact ranges.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <numbers>
#include <random>

#include "common/angles.h"
#include "pgm/materials.h"
#include "qualify/range_noise/range_noise_cli.h"
#include "qualify/range_noise/range_noise_fit.h"
#include "sensor/frames.h"
#include "sensor/pcl_generator.h"
#include "sensor/range_noise.h"
#include "tests/support/temp_path.h"

using namespace lidarsim::qualify;
namespace pgm = lidarsim::pgm;

namespace {

using lidarsim::kDeg;

struct SyntheticScan {
  std::vector<pgm::Point> points;
  std::vector<int> rows;
  std::vector<float> incidence;  // true, rad
};

// Sensor 1.73 m above a flat road; building walls along y = 12 m (left) and y = -15 m (right),
// each seen from ~0 to ~85 deg incidence along a row. Rows at `elevations_deg` (default 48 rows
// from +2 to -22 deg), 2000 points per row (0.18 deg, like an HDL-64E at 10 Hz), in firing order
// (row by row, azimuth rising from -pi). sigma(r) = sqrt(a^2 + (b r)^2) along each beam.
SyntheticScan scene(double a, double b, std::uint64_t seed, std::vector<double> elevations_deg = {}) {
  if (elevations_deg.empty())
    for (int r = 0; r < 48; ++r) elevations_deg.push_back(2 - 24.0 * r / 47);
  SyntheticScan s;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  const int cols = 2000;
  const double h = 1.73, left_y = 12, right_y = -15;
  for (int r = 0; r < static_cast<int>(elevations_deg.size()); ++r) {
    const double el = elevations_deg[r] * kDeg;
    for (int c = 0; c < cols; ++c) {
      const double az = -std::numbers::pi + 2 * std::numbers::pi * (c + 0.5) / cols;
      const double ux = std::cos(el) * std::cos(az), uy = std::cos(el) * std::sin(az), uz = std::sin(el);
      double t = 1e9, inc = 0;
      int cls = -1;
      if (uz < 0) t = -h / uz, inc = std::acos(-uz), cls = pgm::cls::road;
      if (uy > 0 && left_y / uy < t) t = left_y / uy, inc = std::acos(uy), cls = pgm::cls::building;
      if (uy < 0 && right_y / uy < t) t = right_y / uy, inc = std::acos(-uy), cls = pgm::cls::building;
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

TEST(RangeNoiseFit, CommandWritesTheModelItMeasuresOnARecordedScan) {
  // lidar-qualify range-noise on a scan written in the SemanticKITTI layout (HDL-64E elevations,
  // firing order, road = label 40, building = 50) with sigma = 3 cm along the beam: the model it
  // writes gives 3 cm back at every range of its table, and records its command and the datasheet.
  const double sigma = 0.03;
  std::vector<double> elevations;
  for (double e : pgm::BeamLayout::hdl64e().elevations_rad) elevations.push_back(e / kDeg);
  const auto s = scene(sigma, 0, 6, elevations);
  const auto dir = lidarsim::testing::temp_path("range_noise_cli");
  std::filesystem::create_directories(dir / "velodyne");
  std::filesystem::create_directories(dir / "labels");
  std::vector<float> xyzi;
  std::vector<std::uint32_t> labels;
  for (const auto& p : s.points) {
    xyzi.insert(xyzi.end(), {p.x, p.y, p.z, p.intensity});
    labels.push_back(p.class_id == pgm::cls::road ? 40u : 50u);
  }
  std::ofstream(dir / "velodyne/000000.bin", std::ios::binary)
      .write(reinterpret_cast<const char*>(xyzi.data()), static_cast<std::streamsize>(xyzi.size() * sizeof(float)));
  std::ofstream(dir / "labels/000000.label", std::ios::binary)
      .write(reinterpret_cast<const char*>(labels.data()), static_cast<std::streamsize>(labels.size() * 4));
  const std::string sk = dir.string(), out = (dir / "model.json").string();
  std::vector<std::string> args = {"range-noise", "--semantickitti", sk, "--classes", "road,building", "--out", out};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  ::testing::internal::CaptureStdout();
  ASSERT_EQ(run_range_noise(static_cast<int>(argv.size()), argv.data()), 0);
  const std::string printed = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(printed.find("spread by range"), std::string::npos);
  const auto model = lidarsim::sensor::load_range_noise_model(out);
  EXPECT_EQ(model.sensor, "hdl64e");
  ASSERT_GE(model.table_range_m.size(), 5u);
  for (std::size_t i = 0; i < model.table_range_m.size(); ++i)
    EXPECT_NEAR(model.table_sigma_m[i], sigma, 0.1 * sigma) << "range " << model.table_range_m[i];
  std::ifstream in(out);
  const auto j = nlohmann::json::parse(in);
  EXPECT_NE(j["command"].get<std::string>().find("lidar-qualify range-noise --semantickitti"), std::string::npos);
  EXPECT_EQ(j["datasheet"]["sigma_m"].get<double>(), 0.02);
}
