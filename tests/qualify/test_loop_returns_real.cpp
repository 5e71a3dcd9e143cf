// The closed loop on the return rate on the measured HDL-64E scans (SemanticKITTI seq 00 and 08,
// KITTI object frames; skips without ../shared/data): a planted dropout of one laser is named, and
// on the unplanted scans (three fold assignments) nothing is added. Without the selection-aware
// bound (adding any positive held-out cut) the controls add azimuth or class tables. About 3 s.
#include <gtest/gtest.h>

#include "data/import.h"
#include "qualify/returns/returns_loop.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;

namespace {

struct Scans {
  pgm::BeamLayout layout;
  std::vector<pgm::PolarGridMap> maps;
  std::vector<qualify::ReturnCell> cells;  // before any plant
};

void add(Scans& s, const data::Dataset& d) {
  s.layout = d.layout;
  for (int f = 0; f < d.size(); ++f) {
    s.maps.push_back(d.frame_pgm(f));
    const auto c = qualify::return_cells(pgm::return_target(s.maps.back()), s.layout, static_cast<int>(s.maps.size()) - 1);
    s.cells.insert(s.cells.end(), c.begin(), c.end());
  }
}

}  // namespace

TEST(ReturnLoopStatistical, MeasuredScansLaserDropoutNamedControlsClean) {
  LIDARSIM_REQUIRE_SHARED_DATA(seq00, "semantickitti-seq00-sample");
  LIDARSIM_REQUIRE_SHARED_DATA(seq08, "semantickitti-seq08-mos-sample");
  LIDARSIM_REQUIRE_SHARED_DATA(object, "kitti-object-sample");
  data::ImportOptions o;
  o.extra_channels = {"height"};
  o.include_unlabelled = true;
  Scans s;
  add(s, data::import_semantickitti(seq00, o));
  add(s, data::import_semantickitti(seq08, o));
  add(s, data::import_kitti_object(object, o));

  for (std::uint64_t seed : {1003003ULL, 1003005ULL, 1003007ULL}) {
    qualify::ReturnLoopOptions lo;
    lo.fold_seed = seed;
    const auto r = qualify::loop_returns(s.cells, s.cells, s.layout, lo);
    EXPECT_EQ(r.added_feature, "") << "control, fold seed " << seed;
  }

  qualify::PlantedReturnEffect e;
  e.family = qualify::PlantedReturnFamily::LaserDropout;
  e.row_keep.assign(s.layout.rows(), 1.0);
  e.row_keep[40] = 0.6;
  std::vector<qualify::ReturnCell> planted;
  for (std::size_t k = 0; k < s.maps.size(); ++k) {
    pgm::PolarGridMap m = s.maps[k];
    qualify::plant_returns(m, e, 7, k);
    const auto c = qualify::return_cells(pgm::return_target(m), s.layout, static_cast<int>(k));
    planted.insert(planted.end(), c.begin(), c.end());
  }
  qualify::ReturnLoopOptions lo;
  lo.fold_seed = 3;
  const auto r = qualify::loop_returns(planted, s.cells, s.layout, lo);
  EXPECT_EQ(r.added_feature, "laser");
  EXPECT_LT(r.deviance_after, r.deviance_before);
}
