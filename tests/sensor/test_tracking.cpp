// Hungarian assignment on hand-worked matrices, and the tracker's track management.
#include <gtest/gtest.h>

#include <random>

#include "common/error.h"
#include "sensor/hungarian.h"
#include "sensor/tracking.h"

namespace lidarsim::sensor {
namespace {

TEST(Hungarian, SolvesHandWorkedThreeByThree) {
  // Worked by hand over all 6 permutations: rows -> (1, 0, 2) costs 1 + 2 + 2 = 5, the minimum
  // (row 1's cheapest column, 1, is taken by row 0, which needs it more).
  Eigen::MatrixXd c(3, 3);
  c << 4, 1, 3,
       2, 0, 5,
       3, 2, 2;
  // Permutations: (0,1,2)=4+0+2=6, (0,2,1)=4+5+2=11, (1,0,2)=1+2+2=5, (1,2,0)=1+5+3=9,
  // (2,0,1)=3+2+2=7, (2,1,0)=3+0+3=6.
  HungarianSolver s;
  const auto& a = s.solve(c);
  EXPECT_EQ(a, (std::vector<int>{1, 0, 2}));
  EXPECT_DOUBLE_EQ(s.total_cost(), 5);
}

TEST(Hungarian, BeatsGreedyWhereGreedyIsWrong) {
  // Greedy takes row 0 -> col 0 (cost 1) and must then pay 100 for row 1 -> col 1: 101.
  // The optimum crosses: 2 + 3 = 5.
  Eigen::MatrixXd c(2, 2);
  c << 1, 2,
       3, 100;
  const auto a = solve_assignment(c);
  EXPECT_EQ(a, (std::vector<int>{1, 0}));
}

TEST(Hungarian, RectangularMoreRowsLeavesCheapestUnmatchedOut) {
  // 3 tracks, 2 detections: row 1 is far from both and must stay unassigned.
  Eigen::MatrixXd c(3, 2);
  c << 1, 9,
       8, 8,
       9, 1;
  const auto a = solve_assignment(c);
  EXPECT_EQ(a, (std::vector<int>{0, -1, 1}));
  // More columns than rows.
  Eigen::MatrixXd d(2, 3);
  d << 5, 1, 9,
       1, 5, 9;
  EXPECT_EQ(solve_assignment(d), (std::vector<int>{1, 0}));
}

TEST(Hungarian, MatchesBruteForceOnRandomMatrices) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 10);
  for (int trial = 0; trial < 50; ++trial) {
    Eigen::MatrixXd c(5, 5);
    for (int i = 0; i < 25; ++i) c.data()[i] = u(rng);
    std::vector<int> perm{0, 1, 2, 3, 4};
    double best = 1e300;
    do {
      double s = 0;
      for (int i = 0; i < 5; ++i) s += c(i, perm[i]);
      best = std::min(best, s);
    } while (std::next_permutation(perm.begin(), perm.end()));
    HungarianSolver s;
    s.solve(c);
    EXPECT_NEAR(s.total_cost(), best, 1e-9);
  }
}

Object make(double x, double y, ObjectClass cls = ObjectClass::Car, int id = 0) {
  Object o;
  o.id = id;
  o.cls = cls;
  o.position = {x, y, 0};
  return o;
}

TEST(Tracker, TrackSurvivesFiveFrameOcclusionWithSameIdAndIsDroppedAfterCoastingLimit) {
  TrackerConfig cfg;
  cfg.max_coast_frames = 8;
  Tracker tracker(cfg);
  const double dt = 0.1, v = 10;  // car driving along x at 10 m/s
  int frame = 0;
  auto pos = [&](int f) { return 5 + v * dt * f; };
  int id = -1;
  for (; frame < 10; ++frame) {
    const auto& tr = tracker.update({make(pos(frame), 2)}, frame * dt);
    ASSERT_EQ(tr.size(), 1u);
    id = tr[0].id;
  }
  EXPECT_EQ(tracker.tracks()[0].state, TrackState::Confirmed);
  for (int k = 0; k < 5; ++k, ++frame) {  // hidden: no detection
    const auto& tr = tracker.update({}, frame * dt);
    ASSERT_EQ(tr.size(), 1u);
    EXPECT_EQ(tr[0].state, TrackState::Coasting);
    EXPECT_NEAR(tr[0].object.position.x(), pos(frame), 0.3) << "coasting predicts along the motion";
  }
  for (int k = 0; k < 5; ++k, ++frame) {  // visible again
    const auto& tr = tracker.update({make(pos(frame), 2)}, frame * dt);
    ASSERT_EQ(tr.size(), 1u);
    EXPECT_EQ(tr[0].id, id) << "same id after the occlusion";
    EXPECT_EQ(tr[0].state, TrackState::Confirmed);
  }
  // Gone for good: coasts for exactly max_coast_frames frames, then deleted.
  for (int k = 1; k <= 8; ++k, ++frame) {
    const auto& tr = tracker.update({}, frame * dt);
    ASSERT_EQ(tr.size(), 1u) << "still coasting at miss " << k;
    EXPECT_EQ(tr[0].id, id);
  }
  EXPECT_TRUE(tracker.update({}, frame * dt).empty()) << "deleted after the coasting limit";
  // A new object at the same place gets a new id: ids are never reused.
  ++frame;
  const auto& tr = tracker.update({make(pos(frame), 2)}, frame * dt);
  ASSERT_EQ(tr.size(), 1u);
  EXPECT_NE(tr[0].id, id);
  EXPECT_EQ(tr[0].state, TrackState::Tentative);
}

TEST(Tracker, TwoCrossingPedestriansKeepTheirIds) {
  // Two pedestrians on an X: A from (8,-4) heading (+1,+1), B from (12,-4) heading (-1,+1), at
  // 1.5 m/s; they are at the same point (10,-2) at the same instant. Detections carry 5 cm noise
  // and are fed in shuffled order, so ids cannot come from the input order.
  Tracker tracker;
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0, 0.05);
  const double dt = 0.1, s = 1.5 / std::sqrt(2.0);
  const double t_cross = 2.0 / s;  // seconds until both reach (10, -2)
  const int frames = static_cast<int>(2 * t_cross / dt);
  int id_a = -1, id_b = -1;
  for (int f = 0; f <= frames; ++f) {
    const double t = f * dt;
    Object a = make(8 + s * t + noise(rng), -4 + s * t + noise(rng), ObjectClass::Pedestrian, 100);
    Object b = make(12 - s * t + noise(rng), -4 + s * t + noise(rng), ObjectClass::Pedestrian, 200);
    std::vector<Object> dets = (f % 2) ? std::vector<Object>{b, a} : std::vector<Object>{a, b};
    const auto& tr = tracker.update(dets, t);
    ASSERT_EQ(tr.size(), 2u) << "frame " << f;
    for (const Track& k : tr) {
      if (f == 0) (k.source_id == 100 ? id_a : id_b) = k.id;
      EXPECT_EQ(k.id, k.source_id == 100 ? id_a : id_b) << "frame " << f << ": ids swapped";
    }
  }
  // And at the end, each track is on the right side and moving the right way.
  for (const Track& k : tracker.tracks()) {
    if (k.id == id_a) {
      EXPECT_GT(k.object.velocity.x(), 0.5);
    } else {
      EXPECT_LT(k.object.velocity.x(), -0.5);
    }
  }
}

TEST(Tracker, GateRejectsFarDetectionAndOtherClass) {
  Tracker tracker;
  tracker.update({make(10, 0)}, 0);
  tracker.update({make(10, 0)}, 0.1);
  // A detection 20 m away is a new tentative track; the confirmed one coasts.
  const auto& tr = tracker.update({make(30, 0)}, 0.2);
  ASSERT_EQ(tr.size(), 2u);
  EXPECT_EQ(tr[0].state, TrackState::Coasting);
  EXPECT_EQ(tr[1].state, TrackState::Tentative);
  // A pedestrian at the car's place does not continue the car's track.
  Tracker t2;
  t2.update({make(10, 0)}, 0);
  const auto& tr2 = t2.update({make(10, 0, ObjectClass::Pedestrian)}, 0.1);
  ASSERT_EQ(tr2.size(), 1u);  // the tentative car is deleted on its first miss
  EXPECT_EQ(tr2[0].object.cls, ObjectClass::Pedestrian);
}

TEST(Tracker, RejectsTimeGoingBackwardsAndNonFiniteInput) {
  Tracker tracker;
  tracker.update({make(1, 1)}, 1.0);
  EXPECT_THROW(tracker.update({}, 0.5), Error);
  Object bad = make(std::nan(""), 0);
  EXPECT_THROW(tracker.update({bad}, 2.0), Error);
  TrackerConfig cfg;
  cfg.measurement_std = -1;
  EXPECT_THROW(Tracker{cfg}, Error);
}

}  // namespace
}  // namespace lidarsim::sensor
