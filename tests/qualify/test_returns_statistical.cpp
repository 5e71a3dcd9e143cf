// Return model on measured scans, held out by place: fitted on the KITTI object frames (other
// drives), scored on SemanticKITTI sequence 00, and the other way round (both HDL-64E, so the
// per-laser table carries over). Skips without ../shared/data.
#include <gtest/gtest.h>

#include <iostream>

#include "data/import.h"
#include "pgm/materials.h"
#include "qualify/returns/returns.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;

namespace {

std::vector<pgm::ReturnTarget> targets_of(const data::Dataset& d) {
  std::vector<pgm::ReturnTarget> t;
  for (int f = 0; f < d.size(); ++f) t.push_back(pgm::return_target(d.frame_pgm(f)));
  return t;
}

sensor::ReturnModel fit(const std::vector<pgm::ReturnTarget>& targets, const pgm::BeamLayout& layout) {
  sensor::ReturnCounts c(layout.rows(), pgm::class_count());
  for (const auto& t : targets) c.add(t);
  return sensor::ReturnModel::fit(c, layout, 20);
}

}  // namespace

TEST(ReturnsStatistical, HeldOutPlaceBeatsEveryBeamReturnsOnKittiDrives) {
  LIDARSIM_REQUIRE_SHARED_DATA(seq00, "semantickitti-seq00-sample");
  LIDARSIM_REQUIRE_SHARED_DATA(object, "kitti-object-more");
  data::ImportOptions o;
  o.extra_channels = {"height"};
  o.include_unlabelled = true;
  const auto a = data::import_semantickitti(seq00, o);
  const auto b = data::import_kitti_object(object, o);
  ASSERT_TRUE(a.layout == b.layout);
  const auto ta = targets_of(a), tb = targets_of(b);
  for (const auto* ts : {&ta, &tb})
    for (const auto& t : *ts) {
      // Mounted 1.73 m above the road; the lower beams' ground spreads over 1.5-2.0 m (pitch, crown).
      EXPECT_GT(t.sensor_height_m, 1.55);
      EXPECT_LT(t.sensor_height_m, 2.0);
      EXPECT_GT(t.drops, 0);
    }
  struct Case {
    const char* name;
    const std::vector<pgm::ReturnTarget>& fit_on;
    const std::vector<pgm::ReturnTarget>& held_out;
  };
  for (const Case& c : {Case{"kitti-object -> seq00", tb, ta}, Case{"seq00 -> kitti-object", ta, tb}}) {
    const auto model = fit(c.fit_on, a.layout);
    const auto s = qualify::score_returns(c.held_out, &model, true);
    const auto base = qualify::score_returns(c.held_out, nullptr, true);
    std::cout << c.name << ": measured rate " << s.measured_rate << ", predicted " << s.predicted_rate << ", AUROC "
              << s.auroc << ", TV laser " << s.tv_laser << " (every beam returns: " << base.tv_laser << "), range "
              << s.tv_range << " (" << base.tv_range << "), class " << s.tv_class << " (" << base.tv_class << ")\n";
    EXPECT_GT(s.auroc, 0.6) << c.name;
    EXPECT_LT(s.tv_laser, 0.5 * base.tv_laser) << c.name;
    EXPECT_LT(s.tv_range, 0.5 * base.tv_range) << c.name;
    EXPECT_LT(s.brier, base.brier) << c.name;
  }
}
