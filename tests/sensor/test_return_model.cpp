// Return model (sensor/return_model.h): shrinkage, JSON, and its use by the PCL generator —
// off by default, deterministic per (seed, frame, cell) whatever the thread count, and keeping
// returns at the fitted rate.
#include <gtest/gtest.h>

#include <omp.h>

#include <cmath>
#include <memory>

#include "common/error.h"
#include "pgm/materials.h"
#include "sensor/frames.h"
#include "sensor/pcl_generator.h"
#include "sensor/return_model.h"

using namespace lidarsim;
using namespace lidarsim::sensor;

namespace {

pgm::BeamLayout layout16() { return pgm::BeamLayout::uniform(16, 2, -15, 512); }

// Row r keeps returns with probability 0.3 + 0.04 r at every range and class: 1000 cells per
// row and 5 m bin from 0 to 60 m, so shrinkage moves nothing by more than ~0.02.
ReturnModel rowwise_model() {
  ReturnCounts c(16, pgm::class_count());
  for (int r = 0; r < 16; ++r)
    for (int b = 0; b < 12; ++b) {
      const std::size_t i = c.index(r, b, pgm::cls::road);
      c.cells[i] = 1000;
      c.returns[i] = std::round(1000 * (0.3 + 0.04 * r));
    }
  return ReturnModel::fit(c, layout16(), 20);
}

std::vector<Object> return_cars() {
  std::vector<Object> objects;
  for (int k = 0; k < 6; ++k) {
    Object o;
    o.id = k;
    o.size = {4.5, 1.8, 1.5};
    o.position = {8.0 * std::cos(k), 8.0 * std::sin(k), 0.75};
    objects.push_back(o);
  }
  return objects;
}

pgm::PolarGridMap run(const PclConfig& cfg, std::uint64_t frame) {
  PclGenerator gen(layout16(), make_pose({0, 0, 1.73}, 0, 0, 0), cfg);
  gen.set_frame(frame);
  auto map = gen.make_map({"height", "incidence"});
  gen.generate(return_cars(), {}, map);
  return map;
}

}  // namespace

TEST(ReturnModel, SparseEntriesShrinkTowardsTheirMarginAndDenseOnesFollowTheirData) {
  ReturnCounts c(2, pgm::class_count());
  // Laser 0, 10-15 m: 10000 road cells at 0.9; 4 car cells that all dropped.
  c.cells[c.index(0, 2, pgm::cls::road)] = 10000;
  c.returns[c.index(0, 2, pgm::cls::road)] = 9000;
  c.cells[c.index(0, 2, pgm::cls::car)] = 4;
  const auto m = ReturnModel::fit(c, pgm::BeamLayout::uniform(2, 1, -1, 16), 20);
  EXPECT_NEAR(m.probability(0, 12, pgm::cls::road), 0.9, 1e-3);
  // (0 + 20 * p_margin) / 24 with p_margin ~ 0.8996: near the margin, far from the raw 0.
  EXPECT_NEAR(m.probability(0, 12, pgm::cls::car), 20 * 0.8996 / 24, 2e-3);
  // Laser 1 has no cells: its entries are the global rate; unlabeled uses laser x range.
  EXPECT_NEAR(m.probability(1, 12, pgm::cls::road), 9000.0 / 10004, 1e-3);
  EXPECT_NEAR(m.probability(0, 12, pgm::cls::unlabeled), 9000.0 / 10004, 1e-3);
}

TEST(ReturnModel, JsonRoundTripKeepsEveryProbabilityAndBadInputNamesTheField) {
  ReturnModel m = rowwise_model();
  m.source = "synthetic";
  m.fit_command = "test";
  const auto back = ReturnModel::from_json(m.to_json(), "mem.json");
  for (int r = 0; r < 16; ++r)
    for (double range : {3.0, 27.0, 200.0})
      for (int k : {0, int(pgm::cls::road), int(pgm::cls::car)})
        EXPECT_EQ(back.probability(r, range, k), m.probability(r, range, k));
  EXPECT_EQ(back.source, "synthetic");
  auto j = m.to_json();
  j["counts"][0][4] = 5000;  // more returns than cells
  try {
    ReturnModel::from_json(j, "bad.json");
    FAIL() << "returns > cells must be rejected";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.json: counts[0]"), std::string::npos) << e.what();
  }
  j = m.to_json();
  j["format"] = "lidarsim-kpi-model";
  EXPECT_THROW(ReturnModel::from_json(j, "bad.json"), Error);
}

TEST(ReturnModel, OffByDefaultTheGeneratorReturnsEveryBeamThatMeetsGeometry) {
  PclConfig off;
  PclConfig on;
  on.returns = std::make_shared<ReturnModel>(rowwise_model());
  const auto a = run(off, 0), b = run(on, 0);
  long long ideal = 0, kept = 0;
  for (std::size_t i = 0; i < a.cells(); ++i) ideal += a.channel("mask")[i] > 0.5f, kept += b.channel("mask")[i] > 0.5f;
  EXPECT_GT(ideal, 4000);
  EXPECT_LT(kept, ideal * 0.85) << "the model must drop returns when on";
  EXPECT_EQ(a.data(), run(off, 7).data()) << "without a model the frame index changes nothing";
}

TEST(ReturnModel, DrawsDependOnlyOnSeedFrameAndCellNotOnThreads) {
  PclConfig cfg;
  cfg.returns = std::make_shared<ReturnModel>(rowwise_model());
  cfg.return_seed = 11;
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const auto one = run(cfg, 3);
  omp_set_num_threads(std::max(2, threads));
  const auto many = run(cfg, 3);
  omp_set_num_threads(threads);
  EXPECT_EQ(one.data(), many.data());
  EXPECT_EQ(one.point_index(), many.point_index());
  EXPECT_NE(run(cfg, 4).data(), one.data()) << "another frame draws anew";
  cfg.return_seed = 12;
  EXPECT_NE(run(cfg, 3).data(), one.data()) << "another seed draws anew";
  // A dropped cell is empty as a beam that met nothing: object id -1, no incidence.
  const auto ideal = run(PclConfig{}, 3);
  for (std::size_t i = 0; i < one.cells(); ++i)
    if (ideal.channel("mask")[i] > 0.5f && one.channel("mask")[i] < 0.5f) {
      EXPECT_EQ(one.channel("object_id")[i], -1.f);
      EXPECT_EQ(one.channel("range")[i], 0.f);
      EXPECT_EQ(one.point_index()[i], -1);
    }
}

TEST(ReturnModel, GeneratedReturnRatePerLaserMatchesTheModel) {
  PclConfig cfg;
  cfg.returns = std::make_shared<ReturnModel>(rowwise_model());
  PclGenerator gen(layout16(), make_pose({0, 0, 1.73}, 0, 0, 0), cfg);
  PclGenerator ideal_gen(layout16(), make_pose({0, 0, 1.73}, 0, 0, 0), PclConfig{});
  auto map = gen.make_map(), ideal = ideal_gen.make_map();
  ideal_gen.generate(return_cars(), {}, ideal);
  std::vector<double> n(16, 0), kept(16, 0), expected(16, 0);
  for (int f = 0; f < 40; ++f) {  // generate() counts frames on
    gen.generate(return_cars(), {}, map);
    for (std::size_t i = 0; i < map.cells(); ++i) {
      if (ideal.channel("mask")[i] < 0.5f) continue;
      const int r = static_cast<int>(i / map.cols());
      n[r] += 1;
      kept[r] += map.channel("mask")[i] > 0.5f;
      expected[r] += cfg.returns->probability(r, ideal.channel("range")[i], static_cast<int>(ideal.channel("class")[i]));
    }
  }
  for (int r = 0; r < 16; ++r) {
    if (n[r] < 1000) continue;
    const double p = expected[r] / n[r], sd = std::sqrt(p * (1 - p) / n[r]);
    EXPECT_NEAR(kept[r] / n[r], p, 4 * sd + 1e-3) << "laser " << r << " over " << n[r] << " cells";
  }
}

TEST(ReturnModel, GeneratorRejectsAModelOfAnotherSensor) {
  PclConfig cfg;
  cfg.returns = std::make_shared<ReturnModel>(rowwise_model());
  EXPECT_THROW(PclGenerator(pgm::BeamLayout::uniform(32, 2, -15, 512), make_pose({0, 0, 1.73}, 0, 0, 0), cfg), Error);
}
