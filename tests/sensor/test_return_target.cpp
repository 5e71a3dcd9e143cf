// The return target (pgm/return_target.h) on scans whose truth is known: cells worked out by hand,
// and ideal scans of the PCL generator (ground, cars, buildings, sky) with returns dropped at
// random, where every empty cell is known to be a drop or sky.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <random>

#include "common/error.h"

#include "pgm/materials.h"
#include "pgm/return_target.h"
#include "sensor/frames.h"
#include "sensor/pcl_generator.h"

using namespace lidarsim;
using pgm::ReturnLabel;
using pgm::ReturnRule;

namespace {

// 8 rows at +3.5 .. -3.5 deg, 64 columns; every cell empty.
pgm::PolarGridMap small_map() {
  return pgm::PolarGridMap(pgm::BeamLayout::uniform(8, 3.5, -3.5, 64), {"range", "class", "mask"});
}

void set_return(pgm::PolarGridMap& m, int row, int col, float range, int cls) {
  m.at(m.channel_index("range"), row, col) = range;
  m.at(m.channel_index("class"), row, col) = static_cast<float>(cls);
  m.at(m.channel_index("mask"), row, col) = 1.f;
}

std::size_t cell(const pgm::PolarGridMap& m, int row, int col) { return static_cast<std::size_t>(row) * m.cols() + col; }

}  // namespace

TEST(ReturnTarget, RowGapBetweenSimilarRangesIsADropWithInterpolatedRangeAndNearerClass) {
  auto m = small_map();
  // Row 1 (above the horizon): a wall at 20 m over columns 10..20 with columns 13, 14 missing;
  // a step from 20 m to 40 m across the missing column 30.
  for (int c = 10; c <= 20; ++c)
    if (c != 13 && c != 14) set_return(m, 1, c, c < 14 ? 20.f : 21.f, c < 14 ? pgm::cls::building : pgm::cls::fence);
  set_return(m, 1, 29, 20.f, pgm::cls::building);
  set_return(m, 1, 31, 40.f, pgm::cls::building);
  pgm::ReturnTargetOptions o;
  o.sensor_height_m = 1.7;  // too few returns to estimate it
  o.reach_m = 50;
  const auto t = pgm::return_target(m, o);
  EXPECT_EQ(t.label[cell(m, 1, 13)], ReturnLabel::Drop);
  EXPECT_EQ(t.rule[cell(m, 1, 13)], ReturnRule::RowGap);
  EXPECT_NEAR(t.range[cell(m, 1, 13)], 20 + 1.0 / 3, 1e-5);  // 1/3 of the way from 20 (col 12) to 21 (col 15)
  EXPECT_EQ(t.class_id[cell(m, 1, 13)], pgm::cls::building);  // nearer: the left return
  EXPECT_EQ(t.class_id[cell(m, 1, 14)], pgm::cls::fence);     // nearer: the right return
  // 20 m vs 40 m differ by more than 10 %: not a row gap, and nothing above row 1 in column 30.
  EXPECT_EQ(t.label[cell(m, 1, 30)], ReturnLabel::Sky);
  // Row 0, above the wall: sky; row 2 under the wall (above the horizon): geometry below a return.
  EXPECT_EQ(t.label[cell(m, 0, 15)], ReturnLabel::Sky);
  EXPECT_EQ(t.rule[cell(m, 2, 15)], ReturnRule::BelowReturn);
  const double el1 = 2.5 * M_PI / 180, el2 = 1.5 * M_PI / 180;
  EXPECT_NEAR(t.range[cell(m, 2, 15)], 21 * std::cos(el1) / std::cos(el2), 1e-4);
}

TEST(ReturnTarget, GroundBelowTheHorizonWithinReachHasGeometryBeyondItIsSky) {
  auto m = small_map();
  set_return(m, 7, 0, 30.f, pgm::cls::road);  // one return so the scan is not empty
  pgm::ReturnTargetOptions o;
  o.sensor_height_m = 1.7;
  o.reach_m = 50;  // ground rule up to 40 m
  const auto t = pgm::return_target(m, o);
  // Row 7 at -3.5 deg: ground at 1.7 / sin(3.5 deg) = 27.8 m; row 6 at -2.5 deg: 39.0 m; row 5
  // at -1.5 deg: 64.9 m, beyond 0.8 x reach.
  EXPECT_EQ(t.rule[cell(m, 7, 40)], ReturnRule::Ground);
  EXPECT_NEAR(t.range[cell(m, 7, 40)], 1.7 / std::sin(3.5 * M_PI / 180), 1e-3);
  EXPECT_EQ(t.rule[cell(m, 6, 40)], ReturnRule::Ground);
  EXPECT_EQ(t.label[cell(m, 5, 40)], ReturnLabel::Sky);
  EXPECT_EQ(t.class_id[cell(m, 6, 0)], pgm::cls::road);  // the return below in its column
  EXPECT_EQ(t.returns, 1);
  EXPECT_EQ(t.drops + t.sky + t.returns, 8 * 64);
}

TEST(ReturnTarget, ALongEmptyRunOnNearGroundIsTheOwnVehicleAShortOneIsDropped) {
  // 8 rows from -10 to -24.5 deg, 256 columns: ground at 1.7 m lies within 4-10 m.
  pgm::PolarGridMap m(pgm::BeamLayout::uniform(8, -10, -24.5, 256), {"range", "class", "mask"});
  for (int r = 0; r < 8; ++r)
    for (int c = 0; c < 256; ++c) {
      const bool front = c < 20 || c >= 236;  // 40 empty columns across the wrap
      const bool gap = r == 7 && c >= 100 && c < 120;  // 20 dropped columns
      if (!(r >= 5 && front) && !gap) set_return(m, r, c, 1.7f / std::sin((10 + 14.5 * r / 7) * M_PI / 180), pgm::cls::road);
    }
  pgm::ReturnTargetOptions o;
  o.sensor_height_m = 1.7;
  o.reach_m = 60;
  const auto t = pgm::return_target(m, o);
  // Rows 5-7 (ground 4.3-4.9 m): the run of 40 is the vehicle; the run of 20 is a drop.
  for (int c : {0, 19, 236, 255}) {
    EXPECT_EQ(t.rule[cell(m, 6, c)], ReturnRule::Vehicle) << c;
    EXPECT_EQ(t.label[cell(m, 6, c)], ReturnLabel::Sky) << c;
  }
  EXPECT_EQ(t.label[cell(m, 7, 110)], ReturnLabel::Drop);
  EXPECT_EQ(t.by_rule[static_cast<int>(ReturnRule::Vehicle)], 3 * 40);
  o.vehicle_run = 0;  // off: the vehicle's cells are ground drops under the returns above
  EXPECT_EQ(pgm::return_target(m, o).label[cell(m, 6, 0)], ReturnLabel::Drop);
}

TEST(ReturnTarget, MissingChannelAndEmptyScanAreClearErrors) {
  pgm::PolarGridMap no_mask(pgm::BeamLayout::uniform(4, 1, -1, 8), {"range", "class"});
  EXPECT_THROW(pgm::return_target(no_mask), Error);
  auto empty = small_map();
  try {
    pgm::return_target(empty);
    FAIL() << "an empty scan has no target";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("mask"), std::string::npos) << e.what();
  }
}

namespace {

// An ideal HDL-64E scan of a street: ground, parked cars, building blocks with gaps of sky, and
// tree canopies (boxes 2.3-6 m above the road, 16-24 m to the side) whose upper part the top
// beams meet while the beams below pass under them into the open: the rule's known error.
pgm::PolarGridMap ideal_street(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  sensor::PclConfig cfg;
  cfg.lanes = false;
  cfg.max_range = 80;
  sensor::PclGenerator gen(pgm::BeamLayout::hdl64e(1024), sensor::make_pose({0, 0, 1.73}, 0, 0, 0), cfg);
  std::vector<sensor::Object> objects;
  int id = 0;
  for (int side : {-1, 1}) {
    for (double x = -60; x < 60; x += 25 + 10 * u(rng)) {  // blocks with gaps between them
      sensor::Object b;
      b.id = id++;
      b.cls = sensor::ObjectClass::Misc;
      b.material = "concrete";
      b.size = {15 + 10 * u(rng), 8, 6 + 15 * u(rng)};
      b.position = {x, side * (12 + 8 * u(rng)), b.size.z() / 2};
      objects.push_back(b);
    }
    for (double x = -50; x < 50; x += 20 + 20 * u(rng)) {  // canopies
      sensor::Object t;
      t.id = id++;
      t.cls = sensor::ObjectClass::Misc;
      t.material = "vegetation";
      t.size = {5, 5, 3.7};
      t.position = {x, side * (16 + 8 * u(rng)), 4.15};
      objects.push_back(t);
    }
    for (double x = -30; x < 40; x += 9 + 8 * u(rng)) {  // parked cars
      sensor::Object c;
      c.id = id++;
      c.size = {4.5, 1.8, 1.5};
      c.position = {x, side * 5.0, 0.75};
      c.heading = 0.1 * (u(rng) - 0.5);
      objects.push_back(c);
    }
  }
  auto map = gen.make_map({"height"});
  gen.generate(objects, {}, map, false);
  return map;
}

struct Recovery {
  double precision = 0, recall = 0, median_range_error = 0;
  long long dropped = 0, sky = 0;
};

// Drops returns of `ideal` (8 % one by one, plus runs along a row starting at 1 % of the cells,
// 1 to 12 cells long) and scores the rule's Drop label against the cells that were dropped.
Recovery drop_and_recover(const pgm::PolarGridMap& ideal, unsigned seed, double* height = nullptr) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  pgm::PolarGridMap m = ideal;
  const float* mask0 = ideal.channel("mask");
  const float* range0 = ideal.channel("range");
  std::vector<char> dropped(m.cells(), 0);
  for (std::size_t i = 0; i < m.cells(); ++i) {
    if (mask0[i] < 0.5f) continue;
    if (u(rng) < 0.08) dropped[i] = 1;
    if (u(rng) < 0.01)
      for (int k = 1, n = 1 + static_cast<int>(12 * u(rng)); k < n && (i + k) % m.cols() != 0; ++k)
        if (mask0[i + k] > 0.5f) dropped[i + k] = 1;
  }
  for (std::size_t i = 0; i < m.cells(); ++i)
    if (dropped[i])
      for (const auto& name : {"range", "class", "material", "mask", "height"}) m.channel(name)[i] = 0.f;
  const auto t = pgm::return_target(m);
  if (height) *height = t.sensor_height_m;
  Recovery r;
  long long tp = 0, fp = 0, fn = 0;
  std::vector<double> err;
  for (std::size_t i = 0; i < m.cells(); ++i) {
    const bool said_drop = t.label[i] == ReturnLabel::Drop;
    if (dropped[i]) ++r.dropped;
    else if (mask0[i] < 0.5f) ++r.sky;
    if (said_drop && dropped[i]) {
      ++tp;
      err.push_back(std::abs(t.range[i] - range0[i]) / range0[i]);
    }
    if (said_drop && !dropped[i]) ++fp;
    if (!said_drop && dropped[i]) ++fn;
  }
  r.precision = tp / std::max(1.0, static_cast<double>(tp + fp));
  r.recall = tp / std::max(1.0, static_cast<double>(tp + fn));
  std::nth_element(err.begin(), err.begin() + err.size() / 2, err.end());
  r.median_range_error = err.empty() ? 1 : err[err.size() / 2];
  return r;
}

}  // namespace

TEST(ReturnTarget, RecoversRandomlyDroppedCellsOfSyntheticStreetsWithHighPrecisionAndRecall) {
  double tp_precision = 0, tp_recall = 0, worst_precision = 1, worst_recall = 1, range_error = 0;
  long long dropped = 0, sky = 0;
  const int scenes = 4;
  for (int s = 0; s < scenes; ++s) {
    const auto ideal = ideal_street(100 + s);
    double h = 0;
    const Recovery r = drop_and_recover(ideal, 200 + s, &h);
    EXPECT_NEAR(h, 1.73, 0.03) << "scene " << s << ": the sensor height from the scan";
    tp_precision += r.precision / scenes, tp_recall += r.recall / scenes;
    worst_precision = std::min(worst_precision, r.precision), worst_recall = std::min(worst_recall, r.recall);
    range_error = std::max(range_error, r.median_range_error);
    dropped += r.dropped, sky += r.sky;
  }
  std::cout << "return target on " << scenes << " synthetic streets: " << dropped << " dropped cells, " << sky
            << " sky cells; precision mean " << tp_precision << " (worst " << worst_precision << "), recall mean "
            << tp_recall << " (worst " << worst_recall << "), median relative range error of recovered drops (worst scene) "
            << range_error << "\n";
  EXPECT_GT(sky, 10000) << "the scenes must hold sky, or precision would prove little";
  EXPECT_GE(worst_precision, 0.97);
  EXPECT_GE(worst_recall, 0.95);
  EXPECT_LT(range_error, 0.03);
}
