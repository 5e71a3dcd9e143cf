// Smoke run of the intensity campaign (bench/loop_campaign_intensity.cpp): one fixed-seed draw
// per planted family on the three labelled SemanticKITTI scans, the loop run blind with its
// lookup base. The full campaign (10+ draws per family, recall and false-add rates) is the bench.
#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "../support/shared_data.h"
#include "data/planted_scans.h"
#include "qualify/intensity.h"

namespace lidarsim::qualify {
namespace {

struct Outcome {
  data::PlantedScanDraw draw;
  data::PlantedScore score;
};

TEST(CampaignIntensityStatistical, OneDrawPerFamilyOnSemanticKitti) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq00-sample");
  const data::Dataset geometry = import_for_qualify(dir);
  IntensityLoopOptions options;
  options.base_model = "lookup";
  // One seed for every family: the control's draw is every draw's twin (the same hidden base and
  // noise), so its excess is the base's own floor.
  const std::uint64_t seed = 2026;
  const data::PlantedScanDraw control_draw = data::draw_planted(data::PlantedScanFamily::Control, seed, geometry, 0.03);
  const double floor =
      data::score_planted(control_draw, loop_intensity(data::plant(geometry, control_draw), options)).excess_before;
  std::map<data::PlantedScanFamily, Outcome> out;
  for (data::PlantedScanFamily f : data::all_planted_families()) {
    const data::PlantedScanDraw draw = data::draw_planted(f, seed, geometry, 0.03);
    const nlohmann::json loop = loop_intensity(data::plant(geometry, draw), options);
    out[f] = {draw, data::score_planted(draw, loop, floor)};
    const auto& s = out[f].score;
    std::printf("%-17s added %-16s excess %.4f -> %.4f (floor %.4f) %s, above floor %s\n", data::to_string(f).c_str(),
                s.added.empty() ? "-" : s.added.c_str(), s.excess_before, s.excess_after, floor, s.hit ? "hit" : "miss",
                s.hit_above_floor ? "hit" : "miss");
  }
  // Nothing is added on the control, nor for a class gain the class x range base already holds.
  EXPECT_TRUE(out[data::PlantedScanFamily::Control].score.added.empty()) << out[data::PlantedScanFamily::Control].score.added;
  EXPECT_TRUE(out[data::PlantedScanFamily::ClassGain].score.added.empty()) << out[data::PlantedScanFamily::ClassGain].score.added;
  // Every effect the base cannot represent leaves an error against the truth above the base's floor.
  for (const auto& [f, o] : out) {
    if (o.draw.effect.scoring == data::PlantedScoring::Detect) {
      EXPECT_GT(o.score.above_floor_before, 0.005) << data::to_string(f);
    }
  }
  // The per-laser families are what the loop was built for: named, and the error above the floor cut.
  EXPECT_TRUE(out[data::PlantedScanFamily::BeamGain].score.hit_above_floor);
  EXPECT_TRUE(out[data::PlantedScanFamily::BadLasers].score.hit_above_floor);
}

}  // namespace
}  // namespace lidarsim::qualify
