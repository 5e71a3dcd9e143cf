// Smoke run of the objects campaign (bench/loop_campaign_objects.cpp): the planted structure is in
// what the loop reads (a lag shifts the position errors by -lag x radial velocity; a dropout window
// empties its azimuths), every family's draw runs through the campaign code with its result
// recorded, and the control adds nothing. One fixed-seed draw per family on 2 short sequences.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <iostream>

#include "bench/campaign_objects.h"
#include "qualify/objects/objects.h"
#include "tests/support/shared_data.h"
#include "tests/support/temp_path.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

data::PlantedTrackingOptions smoke(const fs::path& source, std::uint64_t seed) {
  data::PlantedTrackingOptions o;
  o.source = source, o.seed = seed, o.sequences = 2, o.max_frames = 150;
  return o;
}

qualify::ObjectSet records(const data::PlantedDraw& d, const std::string& name) {
  const fs::path dir = lidarsim::testing::temp_path("campaign_" + name);
  data::write_planted_tracking(dir, d);
  const auto data = qualify::load_tracking(dir, "", "pointrcnn", 2);
  return qualify::collect_objects(data, {0, 1});
}

int feature_index(const std::string& name) {
  return static_cast<int>(std::find(qualify::kObjectFeatures.begin(), qualify::kObjectFeatures.end(), name) -
                          qualify::kObjectFeatures.begin());
}

// Least-squares slope of the along error on the radial velocity, over matched records with
// |radial velocity| <= vmax (a lag shifts a faster object beyond the 2 m matching gate).
double lag_slope(const qualify::ObjectSet& s, double vmax) {
  const int f = feature_index("radial_velocity");
  double sx = 0, sy = 0, sxx = 0, sxy = 0, n = 0;
  for (const auto& r : s.records) {
    if (!r.detected) continue;
    const double x = r.feature[f], y = r.value[0];
    if (std::abs(x) > vmax) continue;
    sx += x, sy += y, sxx += x * x, sxy += x * y, n += 1;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

}  // namespace

// Every family's feature and target are words of the loop's vocabulary.
TEST(CampaignObjectsStatistical, PlantedFeaturesAndTargetsAreTheLoopsWords) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  for (int k = 0; k < data::kPlantedFamilies - 1; ++k) {
    const auto d = data::plan_planted_tracking(static_cast<data::PlantedFamily>(k), smoke(source, 5));
    for (const auto& f : d.effect.features)
      EXPECT_NE(feature_index(f), static_cast<int>(qualify::kObjectFeatures.size())) << f;
    const bool target_known = std::find(qualify::kObjectTargets.begin(), qualify::kObjectTargets.end(),
                                        d.effect.target) != qualify::kObjectTargets.end();
    EXPECT_TRUE(target_known || d.effect.target == data::kFalsePositivesTarget) << d.effect.target;
  }
}

// Same seed, lag vs control: the same windows, base model and draws, so the along error's slope on
// the radial velocity moves by -lag.
TEST(CampaignObjectsStatistical, PlantedLagShiftsPositionsAndDropoutEmptiesItsWindow) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  const auto lag = data::plan_planted_tracking(data::PlantedFamily::Lag, smoke(source, 11));
  const auto control = data::plan_planted_tracking(data::PlantedFamily::Control, smoke(source, 11));
  ASSERT_EQ(lag.sequences[0].name, control.sequences[0].name);
  const double lag_s = lag.effect.params.at("lag_s");
  // Within 1 m of shift: on KITTI the ego's own speed (~10 m/s) moves static objects too, and a lag
  // of 0.3 s shifts them by 3 m, beyond the gate (those become misses and false positives).
  const double vmax = 1.0 / lag_s;
  const double with = lag_slope(records(lag, "lag"), vmax), without = lag_slope(records(control, "control"), vmax);
  std::cout << "  lag " << lag_s << " s: slope " << with << " (control " << without << ")\n";
  EXPECT_NEAR(with - without, -lag_s, 0.15 * lag_s);
  EXPECT_NEAR(without, 0, 0.05);

  const auto drop = data::plan_planted_tracking(data::PlantedFamily::AzimuthDropout, smoke(source, 11));
  const auto s = records(drop, "dropout");
  const double lo = drop.effect.params.at("azimuth_lo_deg") * std::numbers::pi / 180, hi = drop.effect.params.at("azimuth_hi_deg") * std::numbers::pi / 180;
  const int az = feature_index("azimuth");
  double in = 0, in_det = 0, out = 0, out_det = 0;
  for (const auto& r : s.records) {
    const bool inside = r.feature[az] >= lo && r.feature[az] <= hi;
    (inside ? in : out) += 1, (inside ? in_det : out_det) += r.detected;
  }
  std::cout << "  dropout x" << drop.effect.params.at("factor") << ": detected " << in_det << "/" << in << " inside, "
            << out_det << "/" << out << " outside\n";
  ASSERT_GT(in, 20);
  EXPECT_LT(in_det / in, drop.effect.params.at("factor") + 0.15);
  EXPECT_GT(out_det / out, 0.6);
}

// Extra false positives of one class in a range x azimuth cell are counted as false positives there.
TEST(CampaignObjectsStatistical, PlantedFalsePositivesFillTheirCell) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  const auto cell = data::plan_planted_tracking(data::PlantedFamily::FpCell, smoke(source, 13));
  const auto control = data::plan_planted_tracking(data::PlantedFamily::Control, smoke(source, 13));
  const auto& p = cell.effect.params;
  auto inside = [&](const qualify::ObjectSet& s) {
    int n = 0;
    for (const auto& f : s.fp_records)
      n += f.cls == static_cast<int>(p.at("class")) && f.range >= p.at("range_lo_m") && f.range <= p.at("range_hi_m") &&
           f.azimuth >= p.at("azimuth_lo_deg") * std::numbers::pi / 180 &&
           f.azimuth <= p.at("azimuth_hi_deg") * std::numbers::pi / 180;
    return n;
  };
  const auto with = records(cell, "fp_cell"), without = records(control, "fp_control");
  const double expected = p.at("rate_per_frame") * static_cast<double>(with.frame_seq.size());
  std::cout << "  fp cell: " << inside(with) << " false positives inside (control " << inside(without) << "), "
            << expected << " planted\n";
  EXPECT_GT(inside(with) - inside(without), 0.7 * expected);
  EXPECT_LT(inside(with) - inside(without), 1.2 * expected);
}

// One draw per family through the campaign code: it runs, its result is recorded, and the control
// adds nothing. Recall itself is the bench's to measure (bench_loop_campaign_objects).
TEST(CampaignObjectsStatistical, OneDrawPerFamilyRunsAndTheControlAddsNothing) {
  LIDARSIM_REQUIRE_SHARED_DATA(source, "kitti-tracking-gt-pointrcnn");
  const fs::path work = lidarsim::testing::temp_path("campaign_work");
  qualify::LoopOptions lo;
  lo.distribution_seeds = 32;  // the smoke run's budget; the bench uses the command's default
  for (int k = 0; k < data::kPlantedFamilies; ++k) {
    const auto fam = static_cast<data::PlantedFamily>(k);
    const bench::DrawResult r = bench::run_draw(fam, smoke(source, 21), work, lo);
    const nlohmann::json j = bench::to_json(r);
    std::cout << "  " << data::to_string(fam) << ": " << (r.score.recalled ? "recalled" : "missed") << ", added "
              << r.added.dump() << ", " << r.seconds << " s\n";
    EXPECT_TRUE(r.error.empty()) << data::to_string(fam) << ": " << r.error;
    EXPECT_EQ(j["truth"]["family"], data::to_string(fam));
    EXPECT_TRUE(j.contains("recalled") && j.contains("planted_candidates"));
    if (fam == data::PlantedFamily::Control) {
      EXPECT_TRUE(r.added.empty()) << r.added.dump();
      EXPECT_FALSE(r.score.other_add);
    } else {
      EXPECT_FALSE(j["planted_candidates"].empty()) << "the planted feature x target is among the candidates";
    }
  }
}

// The scoring reads every kind of addition from the loop's JSON.
TEST(CampaignObjects, ScoresAddedEffectsSpreadAndFalsePositivesFromTheLoopsJson) {
  data::PlantedEffect lag;
  lag.family = data::PlantedFamily::Lag, lag.feature = "radial_velocity", lag.features = {"radial_velocity"};
  lag.target = "position_along";
  nlohmann::json j = {{"added_effects", {{{"feature", "radial_velocity"}, {"target", "position_along"}, {"before", 1.0},
                                          {"after", 0.6}}}},
                      {"false_positives", {{"added", nullptr}, {"persistence", {{"added", false}}}}}};
  auto s = bench::score_draw(lag, j);
  EXPECT_TRUE(s.named && s.recalled && !s.other_add);
  j["added_effects"][0]["after"] = 0.8;
  s = bench::score_draw(lag, j);
  EXPECT_TRUE(s.named && !s.recalled);
  // Above a noise floor of 0.5 the excess 0.87 -> 0.62 is not cut to 0.7 x; above 0.7, 0.71 -> 0.39 is.
  EXPECT_FALSE(bench::recalled_above_floor(s, 0.5));
  EXPECT_TRUE(bench::recalled_above_floor(s, 0.7));
  EXPECT_FALSE(bench::recalled_above_floor(s, std::nan(""))) << "no ideal: the plain rule";
  j["added_effects"][0]["target"] = "position_across";
  s = bench::score_draw(lag, j);
  EXPECT_TRUE(!s.named && s.other_add) << "the right feature on the wrong target is not the planted effect";
  // A spread form and a false-positive table.
  data::PlantedEffect spread = lag, cell;
  spread.feature = "speed", spread.features = {"speed"};
  cell.feature = "azimuth", cell.features = {"range", "azimuth"}, cell.target = data::kFalsePositivesTarget;
  const nlohmann::json k = {{"added_effects", nlohmann::json::array()},
                            {"added_kind", "spread_table"},
                            {"effect", {{"feature", "speed"}, {"target", "position_along"}}},
                            {"before", 0.5},
                            {"after", 0.1},
                            {"false_positives",
                             {{"added", {{"feature", "range"}, {"error_before", 0.2}, {"error_after", 0.1}}},
                              {"persistence", {{"added", false}}}}}};
  s = bench::score_draw(spread, k);
  EXPECT_TRUE(s.recalled && s.other_add);
  s = bench::score_draw(cell, k);
  EXPECT_TRUE(s.recalled && s.other_add);
  EXPECT_EQ(bench::loop_added_effects(k).size(), 2u);
}

// A planted dropout's error read where it acts: the added term's held-out residuals on the objects
// inside the planted window only. Over every object the cut is diluted by the objects outside,
// whose 0/1 noise no term lowers; the strict figure stays beside it.
TEST(CampaignObjects, ADropoutIsAlsoScoredOnTheObjectsItActsOn) {
  data::PlantedDraw d;
  d.effect.family = data::PlantedFamily::AzimuthDropout, d.effect.feature = "azimuth";
  d.effect.features = {"azimuth"}, d.effect.target = "detection";
  d.effect.params = {{"azimuth_lo_deg", 10.0}, {"azimuth_hi_deg", 30.0}, {"factor", 0.1}};
  qualify::obj::ObjectLoopResult R;
  qualify::obj::Candidate c;
  c.feature = qualify::obj::feature_index("azimuth"), c.target = qualify::kDetectionTarget;
  c.kind = qualify::obj::Kind::RateWindow;
  R.candidates = {c};
  qualify::obj::AddedBias a;
  auto object = [&](double az_deg, double before, double after) {
    std::vector<double> f(qualify::kObjectFeatures.size(), 0.0);
    f[qualify::obj::feature_index("azimuth")] = az_deg * kDeg;
    a.judged.held_features.push_back(f), a.judged.before_r.push_back(before), a.judged.after_r.push_back(after);
  };
  object(20, -0.8, -0.2), object(25, -0.8, -0.2);  // inside: the term cuts the residual
  for (int k = 0; k < 6; ++k) object(-40, 0.3, 0.3);  // outside: 0/1 noise, unchanged
  R.added = {a};
  bench::DrawScore s;
  s.named = true, s.recalled = false;
  bench::score_where_planted(d, R, s);
  EXPECT_EQ(s.where_objects, 2);
  EXPECT_NEAR(s.where_before, 0.8, 1e-12);
  EXPECT_NEAR(s.where_after, 0.2, 1e-12);
  EXPECT_TRUE(s.where_recalled);
  // Not named: nothing to read. Another family: the strict rule.
  bench::DrawScore n;
  bench::score_where_planted(d, R, n);
  EXPECT_FALSE(n.where_recalled);
  d.effect.family = data::PlantedFamily::ClassBias;
  bench::DrawScore e;
  e.named = true, e.recalled = false;
  bench::score_where_planted(d, R, e);
  EXPECT_FALSE(e.where_recalled);
  EXPECT_EQ(e.where_objects, 0);
}

namespace {

std::vector<double> object_features(double radial_velocity, double azimuth_deg, double range) {
  std::vector<double> f(qualify::kObjectFeatures.size(), 0.0);
  f[qualify::obj::feature_index("radial_velocity")] = radial_velocity;
  f[qualify::obj::feature_index("speed")] = std::abs(radial_velocity);
  f[qualify::obj::feature_index("azimuth")] = azimuth_deg * kDeg;
  f[qualify::obj::feature_index("range")] = range;
  return f;
}

qualify::obj::Candidate candidate(const std::string& feature, int target) {
  qualify::obj::Candidate c;
  c.feature = qualify::obj::feature_index(feature), c.target = target;
  return c;
}

}  // namespace

// The truth scorer reads the model's prediction (outcome minus residual) against the hidden
// generating model: a perfect model scores 0 whatever the outcome noise, a model without the effect
// scores the plant's own size, half the effect half of it.
TEST(CampaignObjects, TruthScoreIsZeroForAPerfectModelAndThePlantsSizeWithoutTheEffect) {
  data::PlantedDraw d;
  d.effect.family = data::PlantedFamily::Lag, d.effect.feature = "radial_velocity";
  d.effect.features = {"radial_velocity"}, d.effect.target = "position_along", d.effect.params = {{"lag_s", 0.2}};
  const int along = 0;
  qualify::obj::ObjectLoopResult R;
  R.candidates = {candidate("radial_velocity", along)};
  qualify::obj::AddedBias perfect, without, half;
  double plant = 0;
  for (int i = 0; i < 40; ++i) {
    const double rv = -5 + 0.25 * i, mu = -0.2 * rv, y = mu + (i % 2 ? 0.3 : -0.3);  // outcome noise +-0.3
    plant += mu * mu / 40;
    for (auto* a : {&perfect, &without, &half}) {
      a->judged.held_features.push_back(object_features(rv, 0, 20)), a->judged.held_class.push_back(0);
      a->judged.held_y.push_back(y), a->judged.before_r.push_back(y);  // the starting model predicts 0
    }
    perfect.judged.after_r.push_back(y - mu), without.judged.after_r.push_back(y), half.judged.after_r.push_back(y - mu / 2);
  }
  auto score = [&](const qualify::obj::AddedBias& a) {
    R.added = {a};
    bench::DrawScore s;
    s.named = true;
    bench::truth_score(d, R, s);
    return s;
  };
  const auto p = score(perfect), w = score(without), h = score(half);
  EXPECT_NEAR(p.truth_before, std::sqrt(plant), 1e-12);
  EXPECT_NEAR(p.truth_after, 0, 1e-12);
  EXPECT_TRUE(p.truth_recalled);
  EXPECT_NEAR(w.truth_after, std::sqrt(plant), 1e-12);
  EXPECT_FALSE(w.truth_recalled);
  EXPECT_NEAR(h.truth_after, std::sqrt(plant) / 2, 1e-12);
  EXPECT_EQ(p.truth_objects, 40);
  // Not named: no truth figure, not recalled.
  R.added.clear();
  bench::DrawScore none;
  bench::truth_score(d, R, none);
  EXPECT_FALSE(none.truth_recalled);
  EXPECT_TRUE(std::isnan(none.truth_after));
}

// Detection: predicted against the true detection probability (base x the planted dropout), so
// the 0/1 outcome's Bernoulli noise is not in the figure.
TEST(CampaignObjects, TruthScoreOfADropoutIsTheProbabilityError) {
  data::PlantedDraw d;
  d.effect.family = data::PlantedFamily::AzimuthDropout, d.effect.feature = "azimuth";
  d.effect.features = {"azimuth"}, d.effect.target = "detection";
  d.effect.params = {{"azimuth_lo_deg", 10.0}, {"azimuth_hi_deg", 30.0}, {"factor", 0.2}};
  d.base.detection = {0.9, 0.8, 0.8}, d.base.occlusion_loss = 0.1;
  qualify::obj::ObjectLoopResult R;
  R.candidates = {candidate("azimuth", qualify::kDetectionTarget)};
  qualify::obj::AddedBias a;
  for (int i = 0; i < 20; ++i) {
    const double az = i < 5 ? 20 : -40, p = i < 5 ? 0.18 : 0.9, y = i % 3 ? 1 : 0;
    a.judged.held_features.push_back(object_features(0, az, 20)), a.judged.held_class.push_back(0);
    a.judged.held_y.push_back(y), a.judged.before_r.push_back(y - 0.9), a.judged.after_r.push_back(y - p);
  }
  R.added = {a};
  bench::DrawScore s;
  s.named = true;
  bench::truth_score(d, R, s);
  EXPECT_NEAR(s.truth_before, std::sqrt(5.0 / 20) * 0.72, 1e-12);  // 0.9 - 0.18 on a quarter of the objects
  EXPECT_NEAR(s.truth_after, 0, 1e-12);
  EXPECT_TRUE(s.truth_recalled);
}

// Spread: log of predicted over true sigma; the base sigma scores the planted growth, the grown
// sigma 0.
TEST(CampaignObjects, TruthScoreOfASpreadIsTheLogSigmaError) {
  data::PlantedDraw d;
  d.effect.family = data::PlantedFamily::Spread, d.effect.feature = "range";
  d.effect.features = {"range"}, d.effect.target = "position_across", d.effect.params = {{"gain", 2.0}};
  d.base.across = {0.1, 0.08, 0.1};
  qualify::obj::ObjectLoopResult R;
  R.candidates = {candidate("range", 1)};
  R.spread = qualify::obj::AddedSpread{};
  double plant = 0;
  for (int i = 0; i < 10; ++i) {
    const double range = 4.0 * (i + 1), truth = 0.1 * (1 + 2 * range / 40);
    plant += std::pow(std::log(truth / 0.1), 2) / 10;
    R.spread->held_features.push_back(object_features(0, 0, range)), R.spread->held_class.push_back(0);
    R.spread->sd_before.push_back(0.1), R.spread->sd_after.push_back(truth);
  }
  bench::DrawScore s;
  s.named = true;
  bench::truth_score(d, R, s);
  EXPECT_NEAR(s.truth_before, std::sqrt(plant), 1e-12);
  EXPECT_NEAR(s.truth_after, 0, 1e-12);
  EXPECT_TRUE(s.truth_recalled);
}
