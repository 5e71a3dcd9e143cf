// The object loop's ranking order (qualify/objects/object_loop.h best_per_feature): a candidate ruled out
// by its own interval or by its selection-aware bound must not stand in the way of one that
// passes. The top of the ranking is what the loop judges and adds first; when it was a form that
// could not pass, every other form was left "not tried" and the loop added nothing. Seen on a
// planted azimuth dropout: the rate window scored 0.146 [-0.03, 0.35], the rate table 0.137
// [0.10, 0.18], and the table was never tried.
#include <gtest/gtest.h>

#include <limits>
#include <vector>

#include "qualify/objects/object_loop.h"

using namespace lidarsim::qualify;
using obj::Candidate;
using obj::Kind;

namespace {

Candidate candidate(const char* feature, int target, Kind kind, double score, double lo, double hi,
                    double selection_lower = std::numeric_limits<double>::quiet_NaN()) {
  Candidate c;
  c.feature = obj::feature_index(feature), c.target = target, c.kind = kind, c.score = score;
  c.interval = {lo, hi};
  c.selection_lower = selection_lower;
  return c;
}

}  // namespace

TEST(ObjectLoopRanking, AFormThatPassesRanksBeforeAHigherScoringFormRuledOutByItsInterval) {
  const double thr = 0.05;
  const std::vector<Candidate> cands = {
      candidate("azimuth", kDetectionTarget, Kind::RateWindow, 0.146, -0.03, 0.35),  // interval reaches 0
      candidate("azimuth", kDetectionTarget, Kind::RateTable, 0.137, 0.10, 0.18),    // passes
      candidate("speed", 0, Kind::MeanTable, 0.140, 0.02, 0.25, -0.01),              // selection bound reaches 0
      candidate("size", 2, Kind::MeanTable, 0.120, 0.05, 0.20, 0.01),                // passes
      candidate("track_age", 3, Kind::MeanTable, 0.300, 0.20, 0.40, 0.10),           // passes, best
  };
  const std::vector<int> r = obj::best_per_feature(cands, false, false, thr);
  // Per feature the passing form stands for it; passing features first, by score; then the others.
  ASSERT_EQ(r.size(), 4u);
  EXPECT_EQ(r[0], 4);
  EXPECT_EQ(r[1], 1) << "azimuth's rate table, which passes, stands for azimuth and ranks before size";
  EXPECT_EQ(r[2], 3);
  EXPECT_EQ(r[3], 2) << "speed's form is ruled out by its selection bound, so it ranks last despite its score";
}

TEST(ObjectLoopRanking, WithoutAPassingFormTheBestScoreLeads) {
  const std::vector<Candidate> cands = {
      candidate("azimuth", kDetectionTarget, Kind::RateWindow, 0.04, 0.01, 0.08),  // below the threshold
      candidate("azimuth", kDetectionTarget, Kind::RateTable, 0.03, 0.01, 0.05),
      candidate("speed", 0, Kind::MeanTable, 0.02, -0.01, 0.05),
  };
  const std::vector<int> r = obj::best_per_feature(cands, false, false, 0.05);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0], 0);
  EXPECT_EQ(r[1], 2);
  EXPECT_FALSE(obj::passes_ranking(cands[0], 0.05));
}
