// The intensity loop's rotating folds: the guarded split validates two fixed
// regions of azimuth, so an effect that lives only in the training azimuths never reaches a
// held-out cell and only biases the fit. With the regions rotated over 4 folds every column is
// validated once; the base is fitted per fold and the held-out residuals pooled. A gain over a
// window of azimuth placed entirely inside the fixed split's training columns must then be named
// and cut to <= 0.7 x; with the fixed regions (folds = 1) it is not.
#include <gtest/gtest.h>

#include <filesystem>
#include <iostream>

#include "data/reference_sensor.h"
#include "qualify/intensity/intensity.h"
#include "tests/support/reference_scans.h"

using namespace lidarsim;

namespace {

// Scans with a x0.5 gain over azimuth [-1.2, -0.4] rad: PGM columns 829-958 of 1024, inside the
// guarded split's training arc [806, 986) (regions [64, 192) and [576, 704), guards 102 wide).
data::Dataset window_in_training_columns() {
  data::ReferenceScanOptions o;
  o.effect = data::IntensityEffect::AzimuthWindow;
  o.window_azimuth_lo = -1.2, o.window_azimuth_hi = -0.4;
  o.seed = 31;
  return lidarsim::testing::reference_scans(o, "loop_folds");
}

nlohmann::json run(const data::Dataset& ds, int folds) {
  qualify::IntensityLoopOptions lo;
  lo.base_model = qualify::IntensityBase::Lookup;
  lo.folds = folds;
  const auto j = qualify::loop_intensity(ds, lo);
  std::cout << "  folds " << folds << ": top " << j["ranking"][0].dump() << "\n  added " << j["added_effect"]
            << " via " << j["method"] << ", before " << j["before"] << " after " << j["after"] << "\n";
  return j;
}

}  // namespace

TEST(LoopIntensityFolds, AzimuthWindowInsideTheTrainingColumnsIsNamedAndCutOnlyWithRotatedFolds) {
  const data::Dataset ds = window_in_training_columns();
  {
    // The window is in training columns of the fixed split: the validation regions never see it.
    const auto split = qualify::intensity_split(ds, "guarded", 3);
    const auto roles = split.roles(ds.cols());
    for (int col = 829; col <= 958; ++col) ASSERT_EQ(roles[col], data::kTrain) << col;
  }
  const auto fixed = run(ds, 1);
  EXPECT_NE(fixed["added_effect"], "azimuth") << "the fixed regions cannot see it: the test would prove nothing";

  const auto rotated = run(ds, 4);
  EXPECT_EQ(rotated["validation_folds"], 4);
  EXPECT_EQ(rotated["ranking"][0]["feature"], "azimuth") << rotated["ranking"].dump();
  EXPECT_EQ(rotated["added_effect"], "azimuth");
  EXPECT_LE(rotated["after"].get<double>(), 0.7 * rotated["before"].get<double>());
  // Every cell with a return is held out once: four times the fixed split's held-out share.
  EXPECT_GT(rotated["held_out_cells"].get<double>(), 3.5 * fixed["held_out_cells"].get<double>());
}

// Each candidate's decision is recorded when it is made, with a reason a user acts on.
TEST(LoopIntensityFolds, EveryCandidateCarriesItsDecisionAndReason) {
  const auto j = run(window_in_training_columns(), 4);
  int added = 0;
  for (const auto& k : j["candidates_tested"]) {
    const std::string d = k["decision"], reason = k["reason"];
    EXPECT_FALSE(reason.empty()) << k.dump();
    EXPECT_EQ(reason.rfind(d, 0), 0u) << "the reason starts with the decision: " << k.dump();
    added += d == "added";
    if (k["feature"] == "range") {
      EXPECT_EQ(d, "not ranked") << k.dump();
    }
    if (k["feature"] != "azimuth" && d == "not tried") {
      EXPECT_NE(reason.find("azimuth ranks first"), std::string::npos) << reason;
    }
  }
  EXPECT_EQ(added, 1);
}

TEST(LoopIntensityFolds, FoldsOtherThanOneOrFourAreOneClearError) {
  qualify::IntensityLoopOptions lo;
  lo.base_model = qualify::IntensityBase::Lookup;
  lo.folds = 3;
  data::Dataset empty;
  try {
    qualify::loop_intensity(empty, lo);
    FAIL() << "no error";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("--folds"), std::string::npos) << e.what();
  }
}
