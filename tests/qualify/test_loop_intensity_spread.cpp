// The closed loop on the spread of intensity (qualify/intensity/intensity_spread_loop.h) on the
// reference sensor's geometry with a hidden base intensity and a planted spread whose truth is
// known: it names the feature and cuts the log-scale error against the truth, adds nothing on a
// control, and names the channel a dataset lacks. About a second each.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>

#include "common/error.h"
#include "data/planted_scans.h"
#include "qualify/intensity/intensity_spread_loop.h"
#include "qualify/similarity.h"
#include "tests/support/constant_spread_checkpoint.h"
#include "tests/support/reference_scans.h"
#include "tests/support/shared_data.h"

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

// The geometry with intensity 0.3 + Laplace(0.02 x factor(row)) at every return.
template <class Factor>
data::Dataset laplace_around_constant(Factor&& factor, std::uint64_t seed) {
  data::Dataset ds = spread_geometry();
  qualify::SplitMix rng(seed);
  const auto s = ds.pgm.shape();
  const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
  for (int n = 0; n < s.n; ++n)
    for (std::size_t cell = 0; cell < plane; ++cell) {
      const double u = rng.uniform() - 0.5;
      const double z = -(u < 0 ? -1.0 : 1.0) * std::log(1 - 2 * std::abs(u));  // a unit Laplace
      ds.target.data()[n * plane + cell] = static_cast<float>(0.3 + 0.02 * factor(static_cast<int>(cell / s.w)) * z);
    }
  return ds;
}

}  // namespace

// With a checkpoint, the residual is against its mean and its spread head is the base: a spread
// the head predicts adds nothing, a block of lasers it does not is named.
TEST(LoopIntensitySpread, AgainstACheckpointsSpreadHeadNamesOnlyWhatTheHeadLacks) {
  qualify::IntensitySpreadOptions o;
  o.model = lidarsim::testing::constant_spread_checkpoint("spread_loop_model", 0.3f, 0.02f).string();
  const auto as_predicted = laplace_around_constant([](int) { return 1.0; }, 7);
  const auto residuals = qualify::intensity_spread_residuals(as_predicted, o);
  ASSERT_FALSE(residuals.empty());
  EXPECT_NEAR(residuals[0].offset, std::log(0.02) - 0.5772157, 1e-4);
  const auto control = qualify::loop_intensity_spread(as_predicted, o);
  EXPECT_EQ(control.added_feature, "");
  EXPECT_NEAR(control.error_before, 1.645, 0.1);  // a right Laplace's: the variance of log Exp(1), pi^2 / 6
  const auto wider = laplace_around_constant([](int row) { return row >= 30 && row < 40 ? 2.5 : 1.0; }, 8);
  const auto found = qualify::loop_intensity_spread(wider, o);
  EXPECT_EQ(found.added_feature, "laser");
  // Closing the loop: with the term it found on the head's spread, nothing is left to add.
  o.spread_terms = {found.candidates[found.added].term};
  const auto closed = qualify::loop_intensity_spread(wider, o);
  EXPECT_EQ(closed.added_feature, "");
  EXPECT_LT(closed.error_before, found.error_before);
}

// The loop models log|e| less each residual's offset: a spread per laser that the offsets hold
// adds nothing, the same residuals without them name the laser.
TEST(LoopIntensitySpread, ResidualsOffsetsAreTheBaseTheLoopJudgesAgainst) {
  qualify::SplitMix rng(9);
  std::vector<qualify::LoopResidual> with, without;
  for (int s = 0; s < 2; ++s)
    for (int row = 0; row < 32; ++row)
      for (int k = 0; k < 720; ++k) {
        qualify::LoopResidual x;
        x.scan = s, x.r.row = row, x.r.azimuth_deg = static_cast<float>((k + 0.5) * 0.5);
        x.r.range = static_cast<float>(5 + 50 * rng.uniform()), x.r.class_id = k % 3, x.r.incidence = 0.5f;
        const double sigma = 0.02 * (row < 8 ? 3.0 : 1.0);
        x.r.residual = static_cast<float>(sigma * rng.normal());
        without.push_back(x);
        x.offset = static_cast<float>(std::log(sigma));
        with.push_back(x);
      }
  EXPECT_EQ(qualify::loop_range_noise(without, without).added_feature, "laser");
  EXPECT_EQ(qualify::loop_range_noise(with, with).added_feature, "");
}

TEST(LoopIntensitySpread, ACheckpointWithoutASpreadHeadIsRefusedNamingTheField) {
  qualify::IntensitySpreadOptions o;
  o.model = (lidarsim::testing::source_dir() / "data/models/intensity_unet.h5").string();
  try {
    qualify::intensity_spread_residuals(spread_geometry(), o);
    FAIL() << "expected an error";
  } catch (const Error& err) {
    EXPECT_NE(std::string(err.what()).find("unet.heads"), std::string::npos) << err.what();
  }
}

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
