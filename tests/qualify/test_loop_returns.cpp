// The closed loop on the return rate (qualify/returns/returns_loop.h) on synthetic geometry cells whose
// return probability is known: a planted per-laser dropout must be named "laser" and cut the
// held-out deviance; a control must add nothing. The reference is the same scans before the plant,
// as in the campaign (bench/loop_campaign_returns.cpp).
#include <gtest/gtest.h>

#include <cmath>

#include "common/error.h"
#include "pgm/materials.h"
#include "qualify/returns/returns_loop.h"
#include "qualify/similarity.h"

using namespace lidarsim;

namespace {

struct Synthetic {
  pgm::BeamLayout layout;
  std::vector<qualify::ReturnCell> before, after;
};

// 6 scans of 16 lasers x 256 columns; p = 0.97 falling to 0.87 at 50 m, one class per 32-column
// sector; planted: the returns of `laser` kept with probability `keep`.
Synthetic make(int laser, double keep, std::uint64_t seed) {
  Synthetic s;
  std::vector<double> el;
  for (int r = 0; r < 16; ++r) el.push_back(2.0 - 1.6 * r);
  s.layout = pgm::BeamLayout::from_elevations_deg("synthetic16", el, 256);
  qualify::SplitMix rng(seed);
  for (int scan = 0; scan < 6; ++scan)
    for (int r = 0; r < 16; ++r)
      for (int c = 0; c < 256; ++c) {
        qualify::ReturnCell cell;
        cell.scan = scan, cell.row = r, cell.col = c;
        cell.range = static_cast<float>(3 + 47 * rng.uniform());
        cell.class_id = 1 + (c / 32 + scan) % 4;
        cell.material = pgm::default_material(cell.class_id);
        cell.height = static_cast<float>(cell.range * std::sin(s.layout.elevations_rad[r]));
        cell.azimuth_deg = static_cast<float>(360.0 * (c + 0.5) / 256);
        const double p = 0.97 - 0.1 * cell.range / 50;
        cell.returned = rng.uniform() < p;
        s.before.push_back(cell);
        if (r == laser && cell.returned && rng.uniform() >= keep) cell.returned = false;
        s.after.push_back(cell);
      }
  return s;
}

}  // namespace

TEST(ReturnLoop, NamesAPlantedLaserDropout) {
  const Synthetic s = make(5, 0.5, 11);
  const auto r = qualify::loop_returns(s.after, s.before, s.layout);
  EXPECT_EQ(r.added_feature, "laser");
  EXPECT_LT(r.deviance_after, r.deviance_before * 0.99);
  ASSERT_GE(r.added, 0);
  EXPECT_EQ(r.candidates[r.added].decision, "added");
  // The model gains the effect as a multiplier term, kept through its JSON.
  ASSERT_EQ(r.model.multipliers.size(), 1u);
  const auto back = sensor::ReturnModel::from_json(r.model.to_json(), "test");
  ASSERT_EQ(back.multipliers.size(), 1u);
  const double ratio5 = back.probability_at(5, 100, 20, 2) / back.probability(5, 20, 2);
  const double ratio4 = back.probability_at(4, 100, 20, 2) / back.probability(4, 20, 2);
  EXPECT_NEAR(ratio5, 0.5, 0.06);
  EXPECT_NEAR(ratio4, 1.0, 0.03);
  // The fitted table holds the dropout on laser 5 only.
  const auto& m = r.candidates[r.added].fitted["multiplier"];
  if (r.candidates[r.added].form == qualify::TermForm::table) {
    EXPECT_NEAR(m[5].get<double>(), 0.5, 0.06);
    EXPECT_NEAR(m[4].get<double>(), 1.0, 0.03);
  }
}

TEST(ReturnLoop, AddsNothingOnAControl) {
  const Synthetic s = make(-1, 1.0, 12);
  const auto r = qualify::loop_returns(s.after, s.before, s.layout);
  EXPECT_EQ(r.added_feature, "");
  EXPECT_EQ(r.deviance_after, r.deviance_before);
  EXPECT_TRUE(r.model.multipliers.empty());
  for (const auto& c : r.candidates) EXPECT_EQ(c.decision, "not added") << c.feature << " " << to_string(c.form);
}

TEST(ReturnLoop, NeedsTwoScans) {
  Synthetic s = make(-1, 1.0, 13);
  std::vector<qualify::ReturnCell> one;
  for (const auto& c : s.after)
    if (c.scan == 0) one.push_back(c);
  EXPECT_THROW(qualify::loop_returns(one, s.before, s.layout), Error);
}
