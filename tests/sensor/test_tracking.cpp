// Hungarian assignment on hand-worked matrices, and the tracker's track management.
#include <gtest/gtest.h>

#include <algorithm>
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

namespace lidarsim::sensor {
namespace {

// The gated association (candidates from detections sorted by x, the Hungarian solver per
// connected group) against the whole-matrix Hungarian, recomputed here
// from the tracks before each update: same number of associations and the same total distance
// on crowded frames, where groups of several tracks and detections compete.
TEST(Tracker, GroupedAssociationEqualsWholeMatrixHungarianOnCrowdedFrames) {
  const TrackerConfig cfg;
  Tracker tracker(cfg);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> noise(0, 0.3);
  // 80 objects packed into 30 x 30 m, pedestrians and cars, slow random walks.
  std::vector<Object> truth;
  for (int i = 0; i < 80; ++i) {
    Object o = make(30 * u(rng), 30 * u(rng), i % 3 ? ObjectClass::Pedestrian : ObjectClass::Car, i + 1);
    o.velocity = {2 * u(rng) - 1, 2 * u(rng) - 1, 0};
    truth.push_back(o);
  }
  const double dt = 0.1, r = cfg.measurement_std * cfg.measurement_std, q = cfg.process_accel_std * cfg.process_accel_std;
  int contested = 0, compared = 0;
  for (int f = 0; f < 40; ++f) {
    std::vector<Object> dets;
    for (auto& o : truth) {
      o.position += o.velocity * dt;
      if (u(rng) < 0.1) continue;  // missed now and then
      Object d = o;
      d.position.x() += noise(rng);
      d.position.y() += noise(rng);
      dets.push_back(d);
    }
    std::shuffle(dets.begin(), dets.end(), rng);
    // The reference: predict each track as the tracker does, whole cost matrix, one solve.
    const std::vector<Track> before = tracker.tracks();
    const int nt = static_cast<int>(before.size()), nd = static_cast<int>(dets.size());
    Eigen::MatrixXd cost(std::max(nt, 1), std::max(nd, 1));
    std::vector<Eigen::Vector2d> pos(nt);
    std::vector<Eigen::Matrix2d> s_inv(nt);
    for (int i = 0; i < nt; ++i) {
      Eigen::Matrix4d F = Eigen::Matrix4d::Identity();
      F(0, 2) = F(1, 3) = dt;
      Eigen::Matrix4d Q = Eigen::Matrix4d::Zero();
      Q(0, 0) = Q(1, 1) = q * dt * dt * dt * dt / 4;
      Q(0, 2) = Q(2, 0) = Q(1, 3) = Q(3, 1) = q * dt * dt * dt / 2;
      Q(2, 2) = Q(3, 3) = q * dt * dt;
      const Eigen::Vector4d x = F * before[i].x;
      const Eigen::Matrix4d P = F * before[i].P * F.transpose() + Q;
      pos[i] = x.head<2>();
      s_inv[i] = (P.topLeftCorner<2, 2>() + r * Eigen::Matrix2d::Identity()).inverse();
      for (int j = 0; j < nd; ++j) {
        const Eigen::Vector2d y = dets[j].position.head<2>() - pos[i];
        const double m2 = y.dot(s_inv[i] * y);
        cost(i, j) = dets[j].cls == before[i].object.cls && m2 <= cfg.gate_chi2 ? m2 : cfg.gate_chi2 * 10 + 1e3;
      }
    }
    int ref_pairs = 0;
    double ref_total = 0;
    if (nt > 0 && nd > 0) {
      const std::vector<int> assign = solve_assignment(cost);
      for (int i = 0; i < nt; ++i)
        if (assign[i] >= 0 && cost(i, assign[i]) <= cfg.gate_chi2) {
          ++ref_pairs;
          ref_total += cost(i, assign[i]);
        }
      for (int i = 0; i < nt; ++i) {
        int gated = 0;
        for (int j = 0; j < nd; ++j) gated += cost(i, j) <= cfg.gate_chi2;
        contested += gated > 1;
      }
    }
    // The tracker's: the surviving tracks keep their order and say which detection they took.
    tracker.update(dets, f * dt);
    int pairs = 0;
    double total = 0;
    for (const Track& t : tracker.tracks()) {
      int i = 0;
      while (i < nt && before[i].id != t.id) ++i;
      if (i == nt || t.detection_index < 0) continue;  // a new track
      const Eigen::Vector2d y = dets[t.detection_index].position.head<2>() - pos[i];
      ++pairs;
      total += y.dot(s_inv[i] * y);
    }
    EXPECT_EQ(pairs, ref_pairs) << "frame " << f;
    EXPECT_NEAR(total, ref_total, 1e-9 * (1 + ref_total)) << "frame " << f;
    compared += nt > 0;
  }
  EXPECT_GT(compared, 30);
  EXPECT_GT(contested, 100) << "the frames must have tracks with more than one detection in their gate";
}

}  // namespace
}  // namespace lidarsim::sensor
