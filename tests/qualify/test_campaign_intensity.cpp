// Smoke run of the intensity campaign (bench/loop_campaign_intensity.cpp): one fixed-seed draw
// per planted family on the three labelled SemanticKITTI scans, the loop run blind with its
// lookup base. The full campaign (10+ draws per family, recall and false-add rates) is the bench.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <vector>

#include "../support/shared_data.h"
#include "data/planted_scans.h"
#include "qualify/intensity/intensity.h"

namespace lidarsim::qualify {
namespace {

struct Outcome {
  data::PlantedScanDraw draw;
  data::PlantedScore score;
};

// The loop on one fixed-seed draw of each family in `families`, scored against the control's floor.
// One seed for every family: the control's draw is every draw's twin (the same hidden base and
// noise), so its excess is the base's own floor.
std::map<data::PlantedScanFamily, Outcome> one_draw_each(const std::filesystem::path& dir,
                                                       const std::vector<data::PlantedScanFamily>& families) {
  const data::Dataset geometry = import_for_qualify(dir);
  IntensityLoopOptions options;
  options.base_model = qualify::IntensityBase::Lookup;
  const std::uint64_t seed = 2026;
  const data::PlantedScanDraw control_draw = data::draw_planted(data::PlantedScanFamily::Control, seed, geometry, 0.03);
  const double floor =
      data::score_planted(control_draw, loop_intensity(data::plant(geometry, control_draw), options)).excess_before;
  std::map<data::PlantedScanFamily, Outcome> out;
  for (data::PlantedScanFamily f : families) {
    const data::PlantedScanDraw draw = data::draw_planted(f, seed, geometry, 0.03);
    const nlohmann::json loop = loop_intensity(data::plant(geometry, draw), options);
    out[f] = {draw, data::score_planted(draw, loop, floor)};
    const auto& s = out[f].score;
    std::printf("%-17s added %-16s excess %.4f -> %.4f (floor %.4f) %s, above floor %s\n", data::to_string(f).c_str(),
                s.added.empty() ? "-" : s.added.c_str(), s.excess_before, s.excess_after, floor, s.hit ? "hit" : "miss",
                s.hit_above_floor ? "hit" : "miss");
  }
  return out;
}

// Every effect the base cannot represent leaves an error against the truth above the base's floor.
void expect_detect_families_above_floor(const std::map<data::PlantedScanFamily, Outcome>& out) {
  for (const auto& [f, o] : out) {
    if (o.draw.effect.scoring == data::PlantedScoring::Detect) {
      EXPECT_GT(o.score.above_floor_before, 0.005) << data::to_string(f);
    }
  }
}

// The families in two tests so that each takes seconds (each runs its own control for the floor):
// those with assertions of their own, then every other family.
const std::vector<data::PlantedScanFamily> kAsserted = {data::PlantedScanFamily::Control, data::PlantedScanFamily::ClassGain,
                                                        data::PlantedScanFamily::BeamGain, data::PlantedScanFamily::BadLasers};

std::vector<data::PlantedScanFamily> other_families() {
  std::vector<data::PlantedScanFamily> rest;
  for (auto f : data::all_planted_families())
    if (std::find(kAsserted.begin(), kAsserted.end(), f) == kAsserted.end()) rest.push_back(f);
  return rest;
}

TEST(CampaignIntensityStatistical, OneDrawOfTheLoopsOwnFamiliesAndTheControlsOnSemanticKitti) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq00-sample");
  auto out = one_draw_each(dir, kAsserted);
  expect_detect_families_above_floor(out);
  // Nothing is added on the control, nor for a class gain the class x range base already holds.
  EXPECT_TRUE(out[data::PlantedScanFamily::Control].score.added.empty()) << out[data::PlantedScanFamily::Control].score.added;
  EXPECT_TRUE(out[data::PlantedScanFamily::ClassGain].score.added.empty()) << out[data::PlantedScanFamily::ClassGain].score.added;
  // The per-laser families are what the loop was built for: named, and the error above the floor cut.
  EXPECT_TRUE(out[data::PlantedScanFamily::BeamGain].score.hit_above_floor);
  EXPECT_TRUE(out[data::PlantedScanFamily::BadLasers].score.hit_above_floor);
}

TEST(CampaignIntensityStatistical, OneDrawOfEveryOtherFamilyOnSemanticKitti) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq00-sample");
  const auto rest = other_families();
  ASSERT_FALSE(rest.empty());
  expect_detect_families_above_floor(one_draw_each(dir, rest));
}

}  // namespace
}  // namespace lidarsim::qualify
