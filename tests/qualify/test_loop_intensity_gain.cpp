// Multiplicative effects: a gain per laser over a base that has already learnt
// each laser's level (a UNet learns it from the training columns; here the lookup-beam base, whose
// per-beam offsets do the same) leaves a residual that scales with the prediction and has nearly
// no mean per row. An additive per-beam table of it explains almost nothing (held-out R^2 below the
// threshold: with additive tables only, as the loop had, nothing would be tried); the gain and
// affine forms must find it, name beam_row and cut the held-out error.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <iostream>

#include "data/reference_sensor.h"
#include "qualify/intensity/intensity.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

nlohmann::json lookup_beam_loop(const data::Dataset& ds) {
  qualify::IntensityLoopOptions lo;
  lo.base_model = qualify::IntensityBase::LookupBeam;
  const auto j = qualify::loop_intensity(ds, lo);
  std::cout << "  top " << j["ranking"][0].dump() << "\n  added " << j["added_effect"] << " via " << j["method"]
            << ", before " << j["before"] << " after " << j["after"] << "\n";
  return j;
}

double additive_per_beam_r2(const nlohmann::json& j) {
  for (const auto& k : j["candidates_tested"])
    if (k["feature"] == "beam_row" && k["form"] == "per-beam table") return k["held_out_r2"].get<double>();
  ADD_FAILURE() << "no per-beam table among the candidates";
  return 1;
}

void expect_gain_found(const nlohmann::json& j, double max_ratio) {
  const double additive = additive_per_beam_r2(j);
  std::cout << "  additive per-beam table R^2 " << additive << "\n";
  EXPECT_LT(additive, j["threshold"].get<double>()) << "the additive table alone must not see it";
  EXPECT_EQ(j["ranking"][0]["feature"], "beam_row") << j["ranking"].dump();
  EXPECT_NE(j["ranking"][0]["form"], "per-beam table");
  EXPECT_EQ(j["added_effect"], "beam_row") << j.value("rejected_effect", nlohmann::json()).dump();
  EXPECT_LE(j["after"].get<double>(), max_ratio * j["before"].get<double>());
}

}  // namespace

TEST(LoopIntensityGain, PerLaserGainOverPerBeamOffsetsIsFoundByAGainFormNotByTheAdditiveTable) {
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_loop_gain_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  data::ReferenceScanOptions o;
  o.effect = data::IntensityEffect::BeamGain;
  o.beam_gain_spread = 0.3;
  o.noise = 0.01;  // half the default: the cut is measured against the noise floor
  o.seed = 31;
  data::write_reference_semantickitti(dir, o);
  const data::Dataset ds = qualify::import_for_qualify(dir);
  fs::remove_all(dir);
  expect_gain_found(lookup_beam_loop(ds), 0.8);
}
