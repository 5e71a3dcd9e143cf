// The closed loop on data from the reference sensor (data/reference_sensor.h): for each hidden
// effect the loop must name the feature it depends on first and cut the held-out error to at
// most 0.7 of what it was; with no hidden effect it must add nothing.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <map>
#include <set>
#include <string>

#include "data/reference_sensor.h"
#include "qualify/intensity/intensity.h"
#include "qualify/objects/objects.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

fs::path reference_fresh_dir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("lidarsim_qualify_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

nlohmann::json object_loop(data::ObjectEffect effect, const fs::path& out_model = {}, double threshold = 0.05,
                           data::ObjectEffect second_effect = data::ObjectEffect::None, bool selection_bound = true) {
  const fs::path dir = reference_fresh_dir("objects_" + data::to_string(effect) + "_" + data::to_string(second_effect));
  data::ReferenceTrackingOptions o;
  o.effect = effect;
  o.second_effect = second_effect;
  o.seed = 17;
  data::write_reference_tracking(dir, o);
  qualify::LoopOptions lo;
  lo.out_model = out_model;
  lo.threshold = threshold;
  lo.selection_bound = selection_bound;
  // 64 seeds in the per-class distribution check (the command's default is 256): the reference
  // effects are large, and the check's decisions these tests read are the same; a quarter of the time.
  lo.distribution_seeds = 64;
  const auto j = qualify::loop_objects(qualify::load_tracking(dir, "", "pointrcnn", 2), lo);
  if (!std::getenv("LIDARSIM_KEEP_REFERENCE")) fs::remove_all(dir);
  return j;
}

nlohmann::json intensity_loop(data::IntensityEffect effect, const qualify::IntensityLoopOptions& options) {
  const fs::path dir = reference_fresh_dir("intensity_" + data::to_string(effect));
  data::ReferenceScanOptions o;
  o.effect = effect;
  o.seed = 23;
  data::write_reference_semantickitti(dir, o);
  const auto j = qualify::loop_intensity(dir, options);
  fs::remove_all(dir);
  return j;
}

// The class x range lookup as base model: the ranking and the refit take a second.
qualify::IntensityLoopOptions lookup_base() {
  qualify::IntensityLoopOptions o;
  o.base_model = qualify::IntensityBase::Lookup;
  return o;
}

// The UNet as base model, retrained with the effect as a new channel: a small, short training
// so that a test takes seconds (the command's defaults train longer).
qualify::IntensityLoopOptions unet_base() {
  qualify::IntensityLoopOptions o;
  o.base_model = qualify::IntensityBase::Unet;
  o.unet.steps = 200;
  o.unet.seeds = 1;
  o.unet.crop_columns = 128;
  return o;
}

void reference_expect_found(const nlohmann::json& j, const std::string& feature) {
  ASSERT_FALSE(j["ranking"].empty());
  std::cout << "  ranking " << j["ranking"].dump().substr(0, 200) << "\n  before " << j["before"] << " after "
            << j["after"] << "\n";
  EXPECT_EQ(j["ranking"][0]["feature"], feature) << j["ranking"].dump();
  EXPECT_EQ(j["added_effect"], feature);
  EXPECT_LE(j["after"].get<double>(), 0.7 * j["before"].get<double>())
      << "before " << j["before"] << " after " << j["after"];
  if (j["domain"] != "objects") return;
  // Re-simulated through the KPI manager with the base model: the same residual as the loop's.
  std::cout << "  re-simulated before " << j["before_simulated"] << " after " << j["after_simulated"] << "\n";
  EXPECT_NEAR(j["before_simulated"].get<double>(), j["before"].get<double>(), 1e-9);
}

// The added term goes into the KPI model, and the simulation with it does what the loop claimed.
void expect_simulated(const nlohmann::json& j) {
  EXPECT_EQ(j["model_term"], j["added_effect"]);
  EXPECT_LE(j["after_simulated"].get<double>(), 0.7 * j["before_simulated"].get<double>());
  EXPECT_NEAR(j["after_simulated"].get<double>(), j["after"].get<double>(), 0.01 * j["before"].get<double>())
      << "the KPI manager computes the feature as the loop does";
}

}  // namespace

TEST(LoopObjectsStatistical, NamesVelocityLagAndCutsHeldOutErrorBelow70Percent) {
  const fs::path model = reference_fresh_dir("velocity_lag_model.json");
  const auto j = object_loop(data::ObjectEffect::VelocityLag, model);
  reference_expect_found(j, "radial_velocity");
  expect_simulated(j);
  // The written model carries the term on the loop's target, and loads (validated).
  const sensor::KpiModel m = sensor::load_kpi_model(model);
  const auto& ct = m.classes.at("Car").errors[int(sensor::KpiParam::PositionAlong)].conditional;
  EXPECT_EQ(ct.feature, "radial_velocity");
  EXPECT_EQ(ct.bias.size(), ct.edges.size());
  EXPECT_FALSE(m.classes.at("Car").errors[int(sensor::KpiParam::Width)].conditional.present());
  fs::remove(model);
}

TEST(LoopObjectsStatistical, NamesTruncationSizeErrorAndCutsHeldOutErrorBelow70Percent) {
  const fs::path model = reference_fresh_dir("truncation_model.json");
  const auto j = object_loop(data::ObjectEffect::TruncationSize, model);
  reference_expect_found(j, "truncation");
  // sensor::Object carries truncation, so the term goes into the KPI model and the manager with it
  // does what the loop claimed.
  expect_simulated(j);
  EXPECT_EQ(j["model_term_on"], "errors.length");
  EXPECT_FALSE(j.contains("model_term_absent_because")) << j["model_term_absent_because"];
  const sensor::KpiModel m = sensor::load_kpi_model(model);
  const auto& ct = m.classes.at("Car").errors[int(sensor::KpiParam::Length)].conditional;
  EXPECT_EQ(ct.feature, "truncation");
  // A truncated box is measured short (-0.45 x truncation x length, ~4.2 m cars): the most
  // truncated bin's bias is at least 1 m below the least truncated one's.
  ASSERT_GE(ct.bias.size(), 2u);
  EXPECT_LT(ct.bias.back(), ct.bias.front() - 1.0) << nlohmann::json(ct.bias).dump();
  fs::remove(model);
}

// The KPI model conditions detection and the errors' spread on the visibility bin (occlusion), not
// an error's mean: a length error by occlusion level must be ranked, named and cut like any other.
TEST(LoopObjectsStatistical, NamesOcclusionSizeErrorAndCutsHeldOutErrorBelow70Percent) {
  const auto j = object_loop(data::ObjectEffect::OcclusionSize);
  reference_expect_found(j, "occlusion");
  EXPECT_EQ(j["ranking"][0]["target"], "length") << j["ranking"].dump();
  if (j.contains("model_term_absent_because"))
    std::cout << "  no model term: " << j["model_term_absent_because"] << "\n";
  // What the model does condition on occlusion stays out of the ranking and is listed as used.
  for (const auto& r : j["ranking"]) EXPECT_NE(r["target"], "detection") << r.dump();
  bool listed = false;
  for (const auto& r : j["used_by_model"]) listed |= r["feature"] == "occlusion" && r["target"] == "detection";
  EXPECT_TRUE(listed) << j["used_by_model"].dump();
  for (const auto& c : j["candidates"]) {
    const bool spread_of_length = c["feature"] == "occlusion" && c["target"] == "length" &&
                                  c["kind"].get<std::string>().rfind("spread", 0) == 0;
    if (!spread_of_length) continue;
    EXPECT_EQ(c["decision"].get<std::string>().rfind("not ranked", 0), 0u) << c.dump();
  }
}

TEST(LoopObjectsStatistical, NamesAspectDependentAcrossErrorAndCutsHeldOutErrorBelow70Percent) {
  const auto j = object_loop(data::ObjectEffect::AspectAcross);
  reference_expect_found(j, "heading_to_line_of_sight");
  expect_simulated(j);
}

// Two effects on different errors planted together (length by truncation, across by aspect): the
// loop adds the best accepted effect per target, so both become terms of the written model, each
// cuts its own held-out error to <= 0.7, and the model re-simulated with both terms does so too.
TEST(LoopObjectsStatistical, TwoEffectsOnDifferentTargetsAreBothAddedAndBothCutTheirHeldOutError) {
  const fs::path model = reference_fresh_dir("two_effects_model.json");
  const auto j = object_loop(data::ObjectEffect::TruncationSize, model, 0.05, data::ObjectEffect::AspectAcross);
  std::cout << "  added " << j["added_effects"].dump() << "\n";
  ASSERT_TRUE(j["added_effects"].is_array());
  std::map<std::string, nlohmann::json> by_target;
  for (const auto& e : j["added_effects"]) {
    EXPECT_TRUE(by_target.emplace(e["target"].get<std::string>(), e).second) << "one effect per target";
    EXPECT_LE(e["after"].get<double>(), 0.7 * e["before"].get<double>()) << e.dump();
    // A further term is kept only for the classes whose re-simulated held-out distribution did not
    // get worse; here that drops the across term for Cyclist (the shrunk noise misfits its shape), so
    // the re-simulated error of that term falls less than its residual (0.41 -> 0.30 m).
    if (e["distribution_decides"].get<bool>())
      EXPECT_LT(e["after_simulated"].get<double>(), 0.8 * e["before_simulated"].get<double>()) << e.dump();
    else
      EXPECT_LE(e["after_simulated"].get<double>(), 0.7 * e["before_simulated"].get<double>()) << e.dump();
    EXPECT_LT(e["change_interval95"][1].get<double>(), 0.0) << e.dump();
  }
  ASSERT_TRUE(by_target.count("length")) << j["added_effects"].dump();
  ASSERT_TRUE(by_target.count("position_across")) << j["added_effects"].dump();
  EXPECT_EQ(by_target["length"]["feature"], "truncation");
  EXPECT_EQ(by_target["position_across"]["feature"], "heading_to_line_of_sight");
  // The first entry is the single-effect fields' effect.
  EXPECT_EQ(j["added_effects"][0]["feature"], j["added_effect"]);
  const sensor::KpiModel m = sensor::load_kpi_model(model);
  const auto& car = m.classes.at("Car");
  EXPECT_EQ(car.errors[int(sensor::KpiParam::Length)].conditional.feature, "truncation");
  EXPECT_EQ(car.errors[int(sensor::KpiParam::PositionAcross)].conditional.feature, "heading_to_line_of_sight");
  EXPECT_FALSE(car.errors[int(sensor::KpiParam::Width)].conditional.present());
  fs::remove(model);
}

TEST(LoopObjectsStatistical, ControlWithoutHiddenEffectAddsNothing) {
  const auto j = object_loop(data::ObjectEffect::None);
  std::cout << "  control ranking " << j["ranking"].dump().substr(0, 160) << "\n";
  EXPECT_TRUE(j["added_effect"].is_null()) << j["ranking"].dump();
  EXPECT_EQ(j["before"], j["after"]);
  // The cross-fit holds every sequence out exactly once.
  ASSERT_EQ(j["folds"].size(), 2u);
  std::multiset<std::string> held;
  for (const auto& f : j["folds"])
    for (const auto& s : f["held_out_sequences"]) held.insert(s.get<std::string>());
  EXPECT_EQ(held.size(), 2u);
  EXPECT_EQ(std::set<std::string>(held.begin(), held.end()).size(), 2u);
}

// With the threshold and the selection-aware bound off (which refuses it first, test_loop_selection.cpp),
// the control set's best feature is a candidate; the refit must not beat the track-to-track noise,
// so the loop names it as rejected and adds nothing.
TEST(LoopObjectsStatistical, ControlCandidateIsRejectedByTheChangeTest) {
  const auto j = object_loop(data::ObjectEffect::None, {}, -1.0, data::ObjectEffect::None, false);
  ASSERT_TRUE(j.contains("rejected_effect")) << j.dump().substr(0, 400);
  EXPECT_EQ(j["rejected_effect"]["feature"], j["ranking"][0]["feature"]);
  EXPECT_GE(j["change_interval95"][1].get<double>(), 0.0);
  EXPECT_TRUE(j["added_effects"].empty()) << j["added_effects"].dump();
  // With the threshold at -1 every spread form clears it too, and is then judged by its own
  // interval and selection bound alone (on this set a spread_line by track age passes them: the
  // reference sensor's errors are not equally spread over a track's life). Only a bias form must
  // meet the change test.
  const bool spread = j["added_kind"].is_string() && j["added_kind"].get<std::string>().rfind("spread", 0) == 0;
  std::cout << "  added " << j["added_kind"] << " on " << j["added_effect"] << "\n";
  if (!spread) {
    EXPECT_TRUE(j["added_effect"].is_null());
    EXPECT_EQ(j["before"], j["after"]);
    EXPECT_TRUE(j["model_term"].is_null());
  }
}

TEST(LoopIntensity, NamesIncidenceFalloffAndCutsHeldOutErrorBelow70Percent) {
  reference_expect_found(intensity_loop(data::IntensityEffect::Incidence, lookup_base()), "incidence_angle");
}

TEST(LoopIntensity, NamesHeightGainAndCutsHeldOutErrorBelow70Percent) {
  reference_expect_found(intensity_loop(data::IntensityEffect::Height, lookup_base()), "height");
}

TEST(LoopIntensity, NamesAzimuthGainAndCutsHeldOutErrorBelow70Percent) {
  reference_expect_found(intensity_loop(data::IntensityEffect::Azimuth, lookup_base()), "azimuth");
}

TEST(LoopIntensity, ControlWithoutHiddenEffectAddsNothing) {
  const auto j = intensity_loop(data::IntensityEffect::None, lookup_base());
  std::cout << "  control ranking " << j["ranking"].dump().substr(0, 160) << "\n";
  EXPECT_TRUE(j["added_effect"].is_null()) << j["ranking"].dump();
  EXPECT_EQ(j["before"], j["after"]);
}

// The UNet loop: the hidden effect becomes a new PGM channel and the UNet is retrained with it.
TEST(LoopIntensityUnetStatistical, NamesAzimuthGainAddsItAsAChannelAndCutsHeldOutErrorBelow70Percent) {
  const auto j = intensity_loop(data::IntensityEffect::Azimuth, unet_base());
  reference_expect_found(j, "azimuth");
  EXPECT_NE(j["method"].get<std::string>().find("\"azimuth\""), std::string::npos) << j["method"];
  EXPECT_LE(j["seeds_after"][0].get<double>(), 0.7 * j["seeds_before"][0].get<double>());
}

TEST(LoopIntensityUnetStatistical, NamesIncidenceFalloffAddsItAsAChannelAndCutsHeldOutErrorBelow70Percent) {
  reference_expect_found(intensity_loop(data::IntensityEffect::Incidence, unet_base()), "incidence_angle");
}

TEST(LoopIntensityUnetStatistical, ControlWithoutHiddenEffectAddsNothing) {
  const auto j = intensity_loop(data::IntensityEffect::None, unet_base());
  std::cout << "  control ranking " << j["ranking"].dump().substr(0, 200) << "\n";
  if (j.contains("rejected_effect")) std::cout << "  tried and rejected " << j["rejected_effect"].dump() << "\n";
  EXPECT_TRUE(j["added_effect"].is_null()) << j["ranking"].dump();
  EXPECT_EQ(j["before"], j["after"]);
}
