#include <gtest/gtest.h>

#include <array>
#include <cmath>

#include "common/error.h"
#include "data/baselines.h"
#include "data/import.h"
#include "data/split.h"
#include "pgm/materials.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;

TEST(Split, ValidationIsSectors3_7_11_15OfSixteenAtAnyWidth) {
  const auto split = data::reference_split();
  const auto v1024 = split.validation_columns(1024);
  EXPECT_EQ(std::count(v1024.begin(), v1024.end(), 1), 4 * 64);
  EXPECT_FALSE(v1024[191]);
  EXPECT_TRUE(v1024[192]);  // sector 3 starts at column 192
  EXPECT_TRUE(v1024[255]);
  EXPECT_FALSE(v1024[256]);
  EXPECT_TRUE(v1024[1023]);
  const auto v2048 = split.validation_columns(2048);
  EXPECT_EQ(std::count(v2048.begin(), v2048.end(), 1), 4 * 128);
  for (int c = 0; c < 2048; ++c) EXPECT_EQ(v2048[c], v1024[c / 2]) << c;
  EXPECT_THROW(split.validation_columns(1000), Error);
}

TEST(Baselines, HandWorkedLookupsFallBackToClassThenGlobalMean) {
  // 1 row x 16 columns; only column 3 is validation (sector 3 of 16 at 16 columns).
  data::Dataset d;
  d.channels = {"range", "class"};
  d.layout = pgm::BeamLayout::uniform(1, 0, 0, 16);
  d.pgm.resize({1, 2, 1, 16});
  d.target.resize({1, 1, 1, 16});
  d.mask.resize({1, 1, 1, 16});
  auto set = [&](int col, float range, float cls, float y) {
    d.pgm.at(0, 0, 0, col) = range, d.pgm.at(0, 1, 0, col) = cls, d.target.at(0, 0, 0, col) = y;
    d.mask.at(0, 0, 0, col) = 1;
  };
  set(0, 2, 1, 0.1f);   // class 1 near
  set(1, 12, 1, 0.3f);  // class 1 far
  set(2, 2, 2, 0.8f);   // class 2 near
  set(3, 12, 2, 0.5f);  // validation: class 2 far (range bin unseen for class 2)
  const auto r = data::evaluate_baselines(d);
  ASSERT_EQ(r.size(), 4u);
  const double global = (0.1 + 0.3 + 0.8) / 3;
  EXPECT_NEAR(r[0].validation.mae, std::abs(global - 0.5), 1e-6);
  EXPECT_NEAR(r[1].validation.mae, 0.3, 1e-6);  // class-2 mean 0.8
  EXPECT_NEAR(r[2].validation.mae, 0.3, 1e-6);  // unseen bin -> class mean
  EXPECT_NEAR(r[3].validation.mae, 0.3, 1e-6);  // row 0 of class 2 -> 0.8
  EXPECT_EQ(r[0].validation.cells, 1);
  EXPECT_EQ(r[0].training.cells, 3);
  EXPECT_NEAR(r[2].training.mae, 0.0, 1e-6);  // each training cell is its own (class, bin)
  EXPECT_EQ(data::range_bin(4.99), 0);
  EXPECT_EQ(data::range_bin(5.0), 1);
  EXPECT_EQ(data::range_bin(500.0), data::kRangeBins - 1);
}

// Validates rows, columns and split against DESIGN.md's reference numbers (PyTorch pipeline,
// same three scans): global 0.112, per-class 0.090, class x range 0.082, class x row 0.076 MAE.
// Tolerance 0.002 MAE (the reference is given to 3 decimals; this pipeline measures 0.1118,
// 0.0895, 0.0820, 0.0759).
TEST(BaselinesReal, SemanticKittiBaselinesMatchTheReferenceNumbers) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq00-sample");
  data::ImportOptions o;
  o.extra_channels = {};
  const auto d = data::import_semantickitti(dir, o);
  ASSERT_EQ(d.size(), 3);
  for (const auto& m : d.row_modes) EXPECT_EQ(m, "firing_order");
  const auto r = data::evaluate_baselines(d);
  std::cout << data::baseline_table(r);
  EXPECT_NEAR(r[0].validation.mae, 0.112, 0.002);
  EXPECT_NEAR(r[1].validation.mae, 0.090, 0.002);
  EXPECT_NEAR(r[2].validation.mae, 0.082, 0.002);
  EXPECT_NEAR(r[3].validation.mae, 0.076, 0.002);
  EXPECT_LT(r[3].validation.mae, r[2].validation.mae);
  EXPECT_LT(r[2].validation.mae, r[1].validation.mae);
  EXPECT_LT(r[1].validation.mae, r[0].validation.mae);
}

TEST(BaselinesReal, KittiObjectImportsThreeFramesWithBoxClasses) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "kitti-object-sample");
  data::ImportOptions o;
  o.columns = 2048;
  o.extra_channels = {};
  const auto d = data::import_kitti_object(dir, o);
  ASSERT_EQ(d.size(), 3);
  EXPECT_EQ(d.cols(), 2048);
  for (const auto& m : d.row_modes) EXPECT_EQ(m, "firing_order");
  const auto r = data::evaluate_baselines(d);
  std::cout << data::baseline_table(r);
  // Few labelled points: class helps little, range and row more (ordering only; no reference).
  EXPECT_LE(r[1].validation.mae, r[0].validation.mae + 1e-4);
  EXPECT_LT(r[3].validation.mae, r[0].validation.mae);
}

TEST(Baselines, AcrossPlacesFitOnTheTrainingPlacesOnlyAndScoreEveryHeldOutCell) {
  // Two one-row places: training class 1 at 0.2 (near) and 0.4 (far), class 2 at 0.8; the held-out
  // place has class 1 near at 0.6 and an unseen class 3. Fitted on the held-out cells, every
  // lookup would score 0.
  auto place = [](std::vector<std::array<float, 3>> cells) {  // range, class, target
    data::Dataset d;
    d.channels = {"range", "class"};
    const int w = static_cast<int>(cells.size());
    d.layout = pgm::BeamLayout::uniform(1, 0, 0, w);
    d.pgm.resize({1, 2, 1, w});
    d.target.resize({1, 1, 1, w});
    d.mask.resize({1, 1, 1, w});
    for (int c = 0; c < w; ++c) {
      d.pgm.at(0, 0, 0, c) = cells[c][0], d.pgm.at(0, 1, 0, c) = cells[c][1], d.target.at(0, 0, 0, c) = cells[c][2];
      d.mask.at(0, 0, 0, c) = 1;
    }
    return d;
  };
  const auto train = place({{{2, 1, 0.2f}}, {{12, 1, 0.4f}}, {{2, 2, 0.8f}}});
  const auto held = place({{{2, 1, 0.6f}}, {{2, 3, 0.5f}}});
  const auto r = data::evaluate_baselines_across({&train}, held);
  ASSERT_EQ(r.size(), 4u);
  // global mean 1.4 / 3; per class: class 1 -> 0.3, class 3 unseen -> global.
  const double g = 1.4 / 3;
  EXPECT_EQ(r[0].validation.cells, 2);
  EXPECT_NEAR(r[0].validation.mae, (std::abs(g - 0.6) + std::abs(g - 0.5)) / 2, 1e-6);
  EXPECT_NEAR(r[1].validation.mae, (0.3 + std::abs(g - 0.5)) / 2, 1e-6);
  EXPECT_NEAR(r[2].validation.mae, (0.4 + std::abs(g - 0.5)) / 2, 1e-6);  // class 1, bin [0, 5): 0.2
  EXPECT_EQ(r[0].training.cells, 3);
  // Without the class: every cell is class 0; range bin [0, 5) of training = (0.2 + 0.8) / 2.
  const auto n = data::evaluate_baselines_across({&train}, held, false);
  EXPECT_NEAR(n[2].validation.mae, (std::abs(0.5 - 0.6) + std::abs(0.5 - 0.5)) / 2, 1e-6);
}
