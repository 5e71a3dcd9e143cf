// The per-column occlusion raster against the per-cell reference raster
// (occlusion_reference.h): the same visible fractions within 1 % on crowded random scenes.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>
#include <random>

#include "common/angles.h"
#include "sensor/occlusion.h"
#include "tests/sensor/occlusion_reference.h"

using namespace lidarsim::sensor;

namespace {

using lidarsim::kDeg;

// n boxes of the bench's classes, uniform over a ring of 6..60 m around the sensor (1.73 m above
// the road), random headings: they overlap in angle and often intersect each other. `odd`
// adds boxes hanging above the sensor, tall ones, and one the sensor stands inside (horizontally).
std::vector<Object> crowd(int n, unsigned seed, bool odd) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Object> out;
  for (int i = 0; i < n; ++i) {
    Object o;
    o.id = i + 1;
    const int kind = i % 10;
    o.size = kind < 6 ? Eigen::Vector3d(4.5, 1.8, 1.5)
             : kind == 6 ? Eigen::Vector3d(10, 2.5, 3.5)
             : kind < 9  ? Eigen::Vector3d(0.6, 0.6, 1.8)
                         : Eigen::Vector3d(1.8, 0.6, 1.7);
    // Heights vary by a few cm: two intersecting boxes with roofs in one plane tie exactly in
    // depth on the rays through both roofs, and which one a raster gives a tied cell to is
    // arbitrary (the reference decides it by rounding the stored depth to float).
    o.size.z() += 0.1 * (u(rng) - 0.5);
    const double r = std::sqrt(36 + (3600 - 36) * u(rng)), a = 2 * std::numbers::pi * u(rng);
    o.position = {r * std::cos(a), r * std::sin(a), -1.73 + o.size.z() / 2};
    o.heading = 2 * std::numbers::pi * u(rng) - std::numbers::pi;
    out.push_back(o);
  }
  if (odd) {
    Object over;  // a sign gantry above and ahead
    over.position = {8, 0, 3};
    over.size = {0.5, 12, 1};
    out.push_back(over);
    Object tower;
    tower.position = {-5, 6, 5};
    tower.size = {2, 2, 14};
    tower.heading = 0.3;
    out.push_back(tower);
    Object around;  // the sensor stands (horizontally) inside a bridge deck above it
    around.position = {1, 0.5, 4};
    around.size = {6, 20, 1};
    around.heading = 0.7;
    out.push_back(around);
  }
  for (std::size_t i = 0; i < out.size(); ++i) out[i].id = static_cast<int>(i) + 1;
  return out;
}

void expect_same_fractions(const OcclusionConfig& cfg, int n, unsigned seed, bool odd) {
  std::vector<Object> fast = crowd(n, seed, odd), ref = fast;
  std::vector<LanePolyline> lanes;
  Occlusion occ(cfg);
  occ.apply(fast, lanes);
  reference::ReferenceOcclusion old(cfg);
  old.apply(ref);
  double worst = 0;
  long cells_fast = 0, cells_ref = 0;
  int partly = 0;
  for (std::size_t i = 0; i < fast.size(); ++i) {
    EXPECT_NEAR(fast[i].visible_fraction, ref[i].visible_fraction, 0.01) << "object " << i << " seed " << seed;
    worst = std::max(worst, std::abs(fast[i].visible_fraction - ref[i].visible_fraction));
    cells_fast += occ.footprint_cells()[i];
    cells_ref += old.footprint_cells()[i];
    partly += ref[i].visible_fraction > 0 && ref[i].visible_fraction < 1;
  }
  EXPECT_NEAR(static_cast<double>(cells_fast), static_cast<double>(cells_ref), 0.01 * cells_ref);
  std::cout << "seed " << seed << ": " << fast.size() << " boxes (" << partly << " partly hidden), " << cells_ref
            << " footprint cells (new " << cells_fast << "), largest difference in visible fraction " << worst << "\n";
  EXPECT_GT(partly, 0) << "the scene must exercise partial occlusion";
}

}  // namespace

TEST(OcclusionReference, SameVisibleFractionsAsPerCellRasterWithin1PercentOnPipelineGrid) {
  FieldOfView fov;
  fov.elevation_min = -24.9 * kDeg;
  fov.elevation_max = 2 * kDeg;
  const auto cfg = OcclusionConfig::for_fov(fov, 2 * std::numbers::pi / 1024);
  for (unsigned seed = 1; seed <= 5; ++seed) expect_same_fractions(cfg, 100, seed, false);
}

TEST(OcclusionReference, SameVisibleFractionsWithin1PercentOnFineGridWithOddBoxes) {
  for (unsigned seed = 11; seed <= 13; ++seed) expect_same_fractions(OcclusionConfig{}, 60, seed, true);
}
