// The object loop on an effect of range, a feature the base KPI model bins (10 m bins): every
// candidate is fitted net of those cells, so a detection edge inside a bin is what a range
// candidate scores, and the loop must rank it and add it. Before, every range form counted as
// "used by the model" and was never ranked (a dropout beyond 34.6 m scored 0.149 [0.07, 0.22]
// held out and was listed as "not ranked"), and on two sequences range, fixed to the sensor like
// azimuth, had no folds that could decide on it. Range dropout draw 6 of the campaign
// (bench_loop_campaign_objects --seed 1, counting from 0): real KITTI tracking ground truth, 2
// sequences of 150 frames, detections from the hidden base model with their probability x 0.06
// beyond 27.2 m (inside the model's 20-30 m bin). On 2 sequences range is judged on time blocks.
#include <gtest/gtest.h>

#include <iostream>
#include <string>

#include "bench/campaign_objects.h"
#include "tests/support/shared_data.h"
#include "tests/support/temp_path.h"

namespace fs = std::filesystem;
using namespace lidarsim;

TEST(LoopRangeStatistical, ADetectionDropoutBeyondARangeInsideAModelBinIsRankedAndAdded) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  data::PlantedTrackingOptions o;
  o.source = source, o.seed = 5845383128597012996ULL, o.sequences = 2, o.max_frames = 150;
  qualify::LoopOptions lo;
  lo.distribution_seeds = 32;  // a test's budget; the distribution check does not judge detection terms
  const bench::DrawResult r =
      bench::run_draw(data::PlantedFamily::RangeDropout, o, lidarsim::testing::temp_path("loop_range"), lo);
  ASSERT_TRUE(r.error.empty()) << r.error;
  const auto& p = r.draw.effect.params;
  std::cout << "  dropout x" << p.at("factor") << " beyond " << p.at("range_m") << " m: added " << r.added.dump()
            << "\n  planted candidates " << r.score.candidates.dump() << "\n";
  for (const auto& c : r.score.candidates)
    EXPECT_EQ(c.value("decision", "").rfind("not ranked", 0), std::string::npos) << c.dump();
  EXPECT_TRUE(r.score.named) << "range on detection added";
  EXPECT_FALSE(r.score.other_add);
  EXPECT_LT(r.score.after, r.score.before);
}
