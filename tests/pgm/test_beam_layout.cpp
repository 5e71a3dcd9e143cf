#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "common/error.h"
#include "pgm/beam_layout.h"

using lidarsim::pgm::BeamLayout;
constexpr double kDeg = std::numbers::pi / 180.0;

TEST(BeamLayout, UniformSpacesRowsEvenlyFromTopToBottom) {
  const auto l = BeamLayout::uniform(5, 10, -10, 512);
  ASSERT_EQ(l.rows(), 5);
  EXPECT_EQ(l.columns, 512);
  EXPECT_NEAR(l.elevations_rad[0], 10 * kDeg, 1e-12);
  EXPECT_NEAR(l.elevations_rad[2], 0, 1e-12);
  EXPECT_NEAR(l.elevations_rad[4], -10 * kDeg, 1e-12);
}

TEST(BeamLayout, Hdl64eHas64DescendingRowsSpanningKittiElevations) {
  const auto l = BeamLayout::hdl64e(2048);
  ASSERT_EQ(l.rows(), 64);
  EXPECT_EQ(l.columns, 2048);
  for (int r = 1; r < 64; ++r) EXPECT_LT(l.elevations_rad[r], l.elevations_rad[r - 1]) << r;
  EXPECT_NEAR(l.elevations_rad.front() / kDeg, 2.6, 0.2);
  EXPECT_NEAR(l.elevations_rad.back() / kDeg, -23.7, 0.3);
}

TEST(BeamLayout, ColumnZeroLooksAheadAndColumnsGrowToTheLeft) {
  const auto l = BeamLayout::uniform(2, 1, -1, 1024);
  EXPECT_EQ(l.column_of(1, 0), 0);
  EXPECT_EQ(l.column_of(0, 1), 256);    // left (y > 0) = 90 deg
  EXPECT_EQ(l.column_of(-1, 0), 512);   // behind
  EXPECT_EQ(l.column_of(0, -1), 768);   // right
  EXPECT_EQ(l.column_of(1, -1e-9), 1023);  // just right of ahead wraps to the last bin
  EXPECT_NEAR(l.azimuth_of_column(256), (256.5) * 2 * std::numbers::pi / 1024, 1e-12);
}

TEST(BeamLayout, NearestRowPicksClosestBeamAndRejectsFarOutside) {
  const auto l = BeamLayout::uniform(3, 2, -2, 16);  // 2, 0, -2 deg
  EXPECT_EQ(l.nearest_row(1.1 * kDeg), 0);
  EXPECT_EQ(l.nearest_row(0.9 * kDeg), 1);
  EXPECT_EQ(l.nearest_row(-1.5 * kDeg), 2);
  EXPECT_EQ(l.nearest_row(3.5 * kDeg), 0);    // within one spacing above the top beam
  EXPECT_EQ(l.nearest_row(4.5 * kDeg), -1);   // beyond
  EXPECT_EQ(l.nearest_row(-4.5 * kDeg), -1);
}

TEST(BeamLayout, JsonRoundTripKeepsElevationsAndColumns) {
  const auto l = BeamLayout::hdl64e(2048);
  const auto back = BeamLayout::from_json(l.to_json(), "test");
  EXPECT_EQ(back.name, "hdl64e");
  EXPECT_EQ(back.columns, 2048);
  ASSERT_EQ(back.rows(), 64);
  for (int r = 0; r < 64; ++r) EXPECT_NEAR(back.elevations_rad[r], l.elevations_rad[r], 1e-12);
}

TEST(BeamLayout, JsonUniformSpecIsAccepted) {
  const auto l = BeamLayout::from_json(R"({"name":"uniform","columns":1024,"rows":32,"top_deg":15,"bottom_deg":-15})");
  EXPECT_EQ(l.rows(), 32);
  EXPECT_NEAR(l.elevations_rad[0], 15 * kDeg, 1e-12);
}

TEST(BeamLayout, JsonErrorsNameTheSourceAndField) {
  try {
    BeamLayout::from_json(R"({"elevations_deg":[1,0]})", "ckpt.h5");
    FAIL() << "missing columns accepted";
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("ckpt.h5: columns"), std::string::npos) << e.what();
  }
  EXPECT_THROW(BeamLayout::from_json(R"({"columns":8,"elevations_deg":[0,1]})"), lidarsim::Error);  // ascending
  EXPECT_THROW(BeamLayout::from_json("not json"), lidarsim::Error);
  EXPECT_THROW(BeamLayout::from_elevations_deg("x", {1.0, NAN}, 8), lidarsim::Error);
}

TEST(BeamLayout, FromElevationsSortsTopFirst) {
  const auto l = BeamLayout::from_elevations_deg("s", {-1, 3, 1}, 8);
  EXPECT_NEAR(l.elevations_rad[0], 3 * kDeg, 1e-12);
  EXPECT_NEAR(l.elevations_rad[2], -1 * kDeg, 1e-12);
}
