// The closed loop on the spread of intensity (qualify/intensity/intensity_spread_loop.h) on the
// reference sensor's geometry with a hidden base intensity and a planted spread whose truth is
// known: it names the feature and cuts the log-scale error against the truth, adds nothing on a
// control, and names the channel a dataset lacks. About a second each.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "common/error.h"
#include "data/planted_scans.h"
#include "qualify/intensity/intensity_spread_loop.h"
#include "tests/support/reference_scans.h"

using namespace lidarsim;

namespace {

const data::Dataset& spread_geometry() {
  static const data::Dataset g = [] {
    data::ReferenceScanOptions o;
    o.scans = 2, o.seed = 41;
    return lidarsim::testing::reference_scans(o, "loop_intensity_spread");
  }();
  return g;
}

struct SpreadRun {
  std::vector<qualify::LoopResidual> residuals;
  qualify::RangeLoopResult loop;
  qualify::SpreadTruth truth;
};

SpreadRun run_spread(const qualify::PlantedSpread& e, std::uint64_t seed) {
  const data::PlantedScanDraw base = data::draw_planted(data::PlantedScanFamily::Control, seed, spread_geometry());
  const data::Dataset ds = qualify::plant_spread(spread_geometry(), base, e, seed);
  SpreadRun r;
  r.residuals = qualify::intensity_spread_residuals(ds);
  r.loop = qualify::loop_intensity_spread(ds);
  r.truth = qualify::spread_truth(r.residuals, r.loop, e, base.base.sigma);
  return r;
}

}  // namespace

TEST(LoopIntensitySpread, NamesABlockOfNoisyLasersAndCutsTheErrorAgainstTheTruth) {
  qualify::PlantedSpread e = qualify::draw_planted_spread(qualify::PlantedSpreadFamily::LaserBlock, 3, spread_geometry(), 0.03);
  e.row_first = 20, e.row_last = 29, e.factor = 2.5;
  const SpreadRun r = run_spread(e, 3);
  EXPECT_EQ(r.loop.added_feature, "laser");
  EXPECT_LT(r.loop.error_after, r.loop.error_before);
  EXPECT_GT(r.truth.before, 0.2);  // log(2.5) on a sixth of the rows, part of it in the base's range levels
  EXPECT_LE(r.truth.after, 0.7 * r.truth.before) << r.truth.before << " -> " << r.truth.after;
  // The added term widens the block against the other rows. Less than 2.5 x: the block's rows see
  // a narrow band of ranges, so the base's range levels, fitted first, hold part of it.
  const auto& t = r.loop.candidates[r.loop.added].term;
  ASSERT_EQ(t.feature, "laser");
  EXPECT_GT(t.factor[25] / t.factor[50], 1.5);
}

TEST(LoopIntensitySpread, NamesAWindowOfAzimuth) {
  qualify::PlantedSpread e = qualify::draw_planted_spread(qualify::PlantedSpreadFamily::AzimuthWindow, 4, spread_geometry(), 0.03);
  e.azimuth_start_deg = 100, e.azimuth_width_deg = 70, e.factor = 2.5;
  const SpreadRun r = run_spread(e, 4);
  EXPECT_EQ(r.loop.added_feature, "azimuth");
  EXPECT_LE(r.truth.after, 0.7 * r.truth.before) << r.truth.before << " -> " << r.truth.after;
}

TEST(LoopIntensitySpread, ControlAddsNothing) {
  const qualify::PlantedSpread e = qualify::draw_planted_spread(qualify::PlantedSpreadFamily::Control, 5, spread_geometry(), 0.03);
  const SpreadRun r = run_spread(e, 5);
  EXPECT_EQ(r.loop.added_feature, "") << r.loop.candidates[0].feature << " " << r.loop.candidates[0].score;
  EXPECT_EQ(r.loop.error_after, r.loop.error_before);
}

TEST(LoopIntensitySpread, ResidualsAreAgainstTheOutOfFoldMeanAndCarryThePredictedMeanNotTheMeasured) {
  const data::PlantedScanDraw base = data::draw_planted(data::PlantedScanFamily::Control, 6, spread_geometry());
  const qualify::PlantedSpread e = qualify::draw_planted_spread(qualify::PlantedSpreadFamily::Control, 6, spread_geometry(), 0.03);
  const auto x = qualify::intensity_spread_residuals(qualify::plant_spread(spread_geometry(), base, e, 6));
  long cells = 0;
  const auto& m = spread_geometry().mask;
  for (std::size_t i = 0; i < m.numel(); ++i) cells += m.data()[i] > 0;
  // Every return at most once (the 4 rotated folds validate every column once); those whose class x
  // range key has too few fit cells in their fold are left out.
  EXPECT_LE(static_cast<long>(x.size()), cells);
  EXPECT_GT(static_cast<long>(x.size()), cells / 2);
  // The feature "intensity" is the lookup's mean: over a class x range key it is (nearly) constant
  // while the measured value scatters by sigma; so it never equals mean + residual's spread.
  double spread_of_feature = 0, spread_of_residual = 0;
  for (const auto& r : x) spread_of_residual += r.r.residual * r.r.residual;
  for (const auto& r : x) spread_of_feature += std::pow(r.r.intensity - base.base(r.r.class_id, r.r.range), 2);
  EXPECT_NEAR(std::sqrt(spread_of_residual / x.size()), 0.03, 0.005);
  EXPECT_LT(std::sqrt(spread_of_feature / x.size()), 0.01);
}

TEST(LoopIntensitySpread, ADatasetWithoutIncidenceIsRefusedNamingTheChannel) {
  data::Dataset ds = spread_geometry();
  ds.channels.erase(std::find(ds.channels.begin(), ds.channels.end(), "incidence"));
  try {
    qualify::intensity_spread_residuals(ds);
    FAIL() << "expected an error";
  } catch (const Error& err) {
    EXPECT_NE(std::string(err.what()).find("incidence"), std::string::npos) << err.what();
  }
}
