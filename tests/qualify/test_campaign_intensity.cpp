// Smoke run of the intensity campaign (bench/loop_campaign_intensity.cpp): one fixed-seed draw
// per planted family on the three labelled SemanticKITTI scans, the loop run blind with its
// lookup base. The full campaign (10+ draws per family, recall and false-add rates) is the bench.
#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>

#include "../support/shared_data.h"
#include "data/planted_scans.h"
#include "qualify/intensity/intensity.h"

namespace lidarsim::qualify {
namespace {

constexpr std::uint64_t kSeed = 2026;
constexpr double kNoise = 0.03;

// The loop on one fixed-seed draw of `family`, scored against the base's floor: the excess error
// of the draw's control twin (same seed, so the same hidden base and noise, no effect). The floor
// costs a second loop, so it is run only where a family's check reads it.
data::PlantedScore one_draw(const data::Dataset& geometry, data::PlantedScanFamily family, bool with_floor) {
  IntensityLoopOptions options;
  options.base_model = qualify::IntensityBase::Lookup;
  double floor = 0;
  if (with_floor) {
    const data::PlantedScanDraw control = data::draw_planted(data::PlantedScanFamily::Control, kSeed, geometry, kNoise);
    floor = data::score_planted(control, loop_intensity(data::plant(geometry, control), options)).excess_before;
  }
  const data::PlantedScanDraw draw = data::draw_planted(family, kSeed, geometry, kNoise);
  const data::PlantedScore s = data::score_planted(draw, loop_intensity(data::plant(geometry, draw), options), floor);
  std::printf("%-17s added %-16s excess %.4f -> %.4f (floor %.4f) %s, above floor %s\n", data::to_string(family).c_str(),
              s.added.empty() ? "-" : s.added.c_str(), s.excess_before, s.excess_after, floor, s.hit ? "hit" : "miss",
              s.hit_above_floor ? "hit" : "miss");
  return s;
}

// One test per family, so that each takes seconds (ctest runs them in parallel on CI).
class CampaignIntensityStatistical : public ::testing::TestWithParam<data::PlantedScanFamily> {};

TEST_P(CampaignIntensityStatistical, OneDrawOnSemanticKitti) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq00-sample");
  const data::PlantedScanFamily family = GetParam();
  const data::Dataset geometry = import_for_qualify(dir);
  const data::PlantedScanDraw draw = data::draw_planted(family, kSeed, geometry, kNoise);
  const bool detect = draw.effect.scoring == data::PlantedScoring::Detect;
  const data::PlantedScore s = one_draw(geometry, family, detect);
  // Nothing is added on the control, nor for a class gain the class x range base already holds.
  if (!detect) {
    EXPECT_TRUE(s.added.empty()) << s.added;
    return;
  }
  // Every effect the base cannot represent leaves an error against the truth above the base's floor.
  EXPECT_GT(s.above_floor_before, 0.005);
  // The per-laser families are what the loop was built for: named, and the error above the floor cut.
  if (family == data::PlantedScanFamily::BeamGain || family == data::PlantedScanFamily::BadLasers) {
    EXPECT_TRUE(s.hit_above_floor);
  }
}

INSTANTIATE_TEST_SUITE_P(EveryFamily, CampaignIntensityStatistical, ::testing::ValuesIn(data::all_planted_families()),
                         [](const ::testing::TestParamInfo<data::PlantedScanFamily>& info) {
                           return data::to_string(info.param);
                         });

}  // namespace
}  // namespace lidarsim::qualify
