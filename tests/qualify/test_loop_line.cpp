// The object loop's bias forms on an effect proportional to a feature, judged across folds whose
// feature ranges differ: a position lag makes the error along the line of sight -lag x the radial
// velocity, and with two sequences one fold fits on a sequence of slow traffic and judges one of
// fast traffic. A table of equal-count bins (and a window) is flat beyond the range it was fitted
// on, so it misses most of the effect where the held-out speeds are higher: on the campaign's lag
// draws with 2 sequences the radial-velocity table scored 0.40, -0.24, 0.29, 0.63 and 0.35 held
// out, and a lag of 0.3 s was cut to 0.74 x at best. A straight line per class carries it there.
#include <gtest/gtest.h>

#include <algorithm>
#include <iostream>
#include <random>
#include <vector>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_loop.h"
#include "qualify/objects/object_terms.h"

using namespace lidarsim::qualify;
using obj::Kind;

namespace {

constexpr double kLag = 0.2;  // s

// One sequence's records of position_along: tracks of 10 frames, radial velocity uniform in
// [-vmax, vmax] per track, error -lag x v + noise.
std::vector<ObjectRecord> sequence(int seq, double vmax, std::mt19937_64& rng, double lag = kLag, double curve = 0) {
  std::uniform_real_distribution<double> v(-vmax, vmax);
  std::normal_distribution<double> noise(0, 0.1);
  std::vector<ObjectRecord> out;
  const int f = obj::feature_index("radial_velocity");
  for (int track = 0; track < 60; ++track) {
    const double vt = v(rng);
    for (int frame = 0; frame < 10; ++frame) {
      ObjectRecord r;
      r.seq = seq, r.frame = frame, r.track = track, r.cls = 0, r.detected = true;
      r.feature.assign(kObjectFeatures.size(), 0.0);
      r.feature[f] = vt;
      r.value.fill(0.0);
      r.value[0] = -lag * vt + curve * (vt * vt - vmax * vmax / 3) + noise(rng);
      out.push_back(r);
    }
  }
  return out;
}

obj::Split split_of(const std::vector<ObjectRecord>& recs) {
  obj::Split s;
  for (const ObjectRecord& r : recs) s.r.push_back(r.value[0]), s.rec.push_back(&r);
  return s;
}

// Two folds crossing two sequences on target 0: fold 0 fits a and judges b, fold 1 the other way
// round. The splits point into a and b, which must outlive the folds.
std::array<obj::Fold, 2> crossed_folds(const std::vector<ObjectRecord>& a, const std::vector<ObjectRecord>& b) {
  std::array<obj::Fold, 2> folds;
  for (int k = 0; k < 2; ++k) {
    folds[k].fit_r.assign(kObjectTargetCount, {});
    folds[k].held_r.assign(kObjectTargetCount, {});
    folds[k].win.assign(kObjectTargetCount, {});
    folds[k].fit_r[0] = split_of(k == 0 ? a : b);
    folds[k].held_r[0] = split_of(k == 0 ? b : a);
  }
  return folds;
}

// Bootstrap blocks: each held-out track its own (fold 0's tracks 0-59, fold 1's 60-119).
std::array<std::vector<int>, 2> held_track_blocks(const std::array<obj::Fold, 2>& folds) {
  std::array<std::vector<int>, 2> block;
  for (int k = 0; k < 2; ++k)
    for (const ObjectRecord* r : folds[k].held_r[0].rec) block[k].push_back(60 * k + r->track);
  return block;
}

}  // namespace

TEST(ObjectLoopLine, AnErrorProportionalToAFeatureCarriesToAFoldWithAWiderRangeOfIt) {
  std::mt19937_64 rng(3);
  const std::vector<ObjectRecord> slow = sequence(0, 3, rng), fast = sequence(1, 12, rng);
  // Fold 0 fits the slow sequence and judges the fast one; fold 1 the other way round.
  const std::array<obj::Fold, 2> folds = crossed_folds(slow, fast);
  const std::array<std::vector<int>, 2> block = held_track_blocks(folds);
  const int f = obj::feature_index("radial_velocity");
  double best = -1e9, table = -1e9;
  for (Kind kind : obj::kinds_for(0)) {
    if (obj::is_spread(kind)) continue;
    const obj::Candidate c = obj::judge_candidate(folds, 0, f, kind, 1, 10, block, 120);
    best = std::max(best, c.score);
    if (kind == Kind::MeanTable) table = c.score;
  }
  // The ideal (the true line) leaves only the noise: R^2 about 0.99 here.
  EXPECT_GT(best, 0.95) << "the best bias form on radial_velocity explains the lag held out";
  EXPECT_LT(table, 0.8) << "the table is flat beyond the slow sequence's speeds";
}

TEST(ObjectLoopLine, TheLineTableHoldsTheLineBeyondTheFitRangeAndIsFlatFarBeyond) {
  std::vector<double> x, y;
  for (int i = 0; i <= 200; ++i) x.push_back(-1 + 0.01 * i), y.push_back(0.5 - 2 * x.back());
  const BinnedTable t = obj::fit_line_table(x, y);
  ASSERT_EQ(t.value.size(), static_cast<size_t>(obj::kLineBins));
  // Within one bin's half width (3 x span / kLineBins) of the line, up to a span beyond the data.
  const double tol = 2 * 0.5 * 3 * 2.0 / obj::kLineBins;
  for (double v : {-2.9, -1.0, 0.0, 1.5, 2.9}) EXPECT_NEAR(t(v), 0.5 - 2 * v, tol) << v;
  EXPECT_NEAR(t(10), t(2.99), 1e-12) << "flat beyond span";
}

// A line is a second mean form beside the table: picked on the higher score alone it wins on the
// noise between two near-equal fits (on KITTI, height by box height: line 0.478 [0.387, 0.595],
// table 0.447 [0.382, 0.532]), and a term that does not really help the KPIs enters the model. It is
// ranked only where it beats the table on the same held-out tracks; where the feature's range is
// the same in both folds a 10-bin table carries a line as well, so the table is kept.
TEST(ObjectLoopLine, ALineThatDoesNotBeatTheTableOnTheSameHeldOutTracksIsNotRankedOverIt) {
  std::mt19937_64 rng(4);
  const int f = obj::feature_index("radial_velocity");
  auto ranked_form = [&](double vmax_fit, double vmax_held, obj::Candidate* line_out) {
    // A small lag with a slight curvature (which a table follows and a line does not), well inside
    // the noise: on the same speeds the line and the table fit about equally well.
    const std::vector<ObjectRecord> a = sequence(0, vmax_fit, rng, 0.01, 3e-4), b = sequence(1, vmax_held, rng, 0.01, 3e-4);
    const std::array<obj::Fold, 2> folds = crossed_folds(a, b);
    const std::array<std::vector<int>, 2> block = held_track_blocks(folds);
    std::vector<obj::Candidate> cands;
    for (Kind kind : {Kind::MeanTable, Kind::MeanLine})
      cands.push_back(obj::judge_candidate(folds, 0, f, kind, 1, 10, block, 120));
    obj::compare_lines_with_tables(cands);
    *line_out = cands[1];
    EXPECT_GT(cands[1].score, cands[0].score) << "the line scores higher: picked on the score alone, it would win";
    const std::vector<int> best = obj::best_per_feature(cands, false, false, 0.05);
    return best.empty() ? Kind::RateTable : cands[best.front()].kind;
  };
  obj::Candidate line;
  // The same speeds on both sides: the line's lead over the table is within the track noise.
  EXPECT_EQ(ranked_form(12, 12, &line), Kind::MeanTable);
  std::cout << "  same speeds: line " << line.score << ", minus the table [" << line.vs_table[0] << ", "
            << line.vs_table[1] << "]\n";
  EXPECT_FALSE(obj::line_over_table(line));
  // Slow against fast traffic: the table is flat beyond the fit speeds, the line beats it.
  EXPECT_EQ(ranked_form(3, 12, &line), Kind::MeanLine);
  std::cout << "  slow vs fast: line " << line.score << ", minus the table [" << line.vs_table[0] << ", "
            << line.vs_table[1] << "]\n";
  EXPECT_GT(line.vs_table[0], 0.0);
}
