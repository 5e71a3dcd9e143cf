// The KPI model's optional conditional term: a bias (and sigma scale) per bin
// of a per-object feature, applied by the KPI manager; the file's parse errors; absent = no term.
// Also its twin on detection probability (ClassModel::detection_conditional).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>

#include "common/error.h"
#include "sensor/kpi_manager.h"
#include "sensor/kpi_model.h"
#include "tests/support/shared_data.h"

namespace lidarsim::sensor {
namespace {

// Car only, one range and visibility bin, every parameter N(0, sigma) AR(1) 0.5, no misses/FPs.
KpiModel one_bin_car(double sigma) {
  KpiModel m = default_kpi_model();
  m.range_bin_edges = {0};
  m.visibility_bin_edges = {0};
  ClassModel c = m.classes["Car"];
  for (auto& e : c.errors) {
    e.mean = {0};
    e.sigma = {sigma};
    e.visibility_std_scale = {1};
    e.ar1 = 0.5;
    e.track_std = 0;
    e.innovation = {};
  }
  c.detection_probability = {{1.0}};
  c.false_positive_rate = 0;
  c.heading_flip_probability = 0;
  m.classes.clear();
  m.classes["Car"] = c;
  return m;
}

Object car(int id, Eigen::Vector3d position, Eigen::Vector3d velocity) {
  Object o;
  o.id = id;
  o.position = position;
  o.velocity = velocity;
  o.size = {4, 1.8, 1.5};
  return o;
}

TEST(KpiConditional, SpeedBiasShiftsTheMeanAndScaleTheSpreadOnlyInItsBinOver4000Frames) {
  KpiModel m = one_bin_car(0.1);
  const int along = int(KpiParam::PositionAlong);
  m.classes["Car"].errors[along].conditional = {"speed", {0, 5}, {0, 0.5}, {1, 2}};
  KpiManager kpi(m, 7);
  std::vector<Object> truth, out;
  for (int i = 0; i < 5; ++i) truth.push_back(car(i, {20, -4.0 + 2 * i, -0.9}, {0, 0, 0}));      // speed 0: bin 0
  for (int i = 5; i < 10; ++i) truth.push_back(car(i, {30, -4.0 + 2 * (i - 5), -0.9}, {8, 6, 0}));  // speed 10: bin 1
  double s[2] = {0, 0}, ss[2] = {0, 0}, n[2] = {0, 0};
  for (int f = 0; f < 4000; ++f) {
    kpi.apply(truth, out);
    for (const auto& inj : kpi.injections()) {
      const int b = inj.id >= 5;
      s[b] += inj.error[along], ss[b] += inj.error[along] * inj.error[along], ++n[b];
    }
  }
  const double m0 = s[0] / n[0], m1 = s[1] / n[1];
  const double sd0 = std::sqrt(ss[0] / n[0] - m0 * m0), sd1 = std::sqrt(ss[1] / n[1] - m1 * m1);
  // 20000 samples per bin, AR(1) 0.5 -> ~6700 effective: standard error of the mean <= 0.0025.
  EXPECT_NEAR(m0, 0.0, 0.02) << "slow objects: no bias";
  EXPECT_NEAR(m1, 0.5, 0.02) << "fast objects: the bin's bias 0.5";
  EXPECT_NEAR(sd0, 0.1, 0.01) << "slow objects: sigma as the model (10 %)";
  EXPECT_NEAR(sd1, 0.2, 0.02) << "fast objects: sigma x scale 2 (10 %)";
}

TEST(KpiConditional, FeaturesComeFromTheTruthObjectAndTheTrackAge) {
  KpiModel m = one_bin_car(0.0);  // no noise: error = mean + bias exactly
  auto& e = m.classes["Car"].errors;
  e[int(KpiParam::PositionAlong)].conditional = {"radial_velocity", {-100, 1}, {0, 1}, {}};
  e[int(KpiParam::PositionAcross)].conditional = {"lateral_velocity", {-100, 1}, {0, 2}, {}};
  e[int(KpiParam::Length)].conditional = {"track_age", {0, 3}, {0, 3}, {}};
  e[int(KpiParam::Width)].conditional = {"size", {0, 3}, {0, 4}, {}};
  e[int(KpiParam::Heading)].conditional = {"heading_to_line_of_sight", {0, 1}, {0, 5}, {}};
  KpiManager kpi(m, 1);
  // All heading +x. id 1 at (20, 0) moving +x: receding (radial 3), lateral 0, seen end-on.
  // id 2 at (0, 20) moving +x, length 2: radial 0, seen side-on. id 3 at (20, 0) moving +y:
  // radial 0, lateral +3 (to the left of its heading).
  const Object a = car(1, {20, 0, -0.9}, {3, 0, 0});
  Object b = car(2, {0, 20, -0.9}, {3, 0, 0});
  const Object c = car(3, {20, 0, -0.9}, {0, 3, 0});
  b.size.x() = 2;
  std::vector<Object> out;
  for (int f = 0; f < 5; ++f) {
    kpi.apply({a, b, c}, out);
    const auto& inj = kpi.injections();
    EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::PositionAlong)], 1) << "receding: radial velocity 3";
    EXPECT_DOUBLE_EQ(inj[1].error[int(KpiParam::PositionAlong)], 0) << "crossing: radial velocity 0";
    EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::PositionAcross)], 0) << "moving along its heading";
    EXPECT_DOUBLE_EQ(inj[2].error[int(KpiParam::PositionAcross)], 2) << "moving to the left of its heading";
    EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::Width)], 4) << "length 4 >= 3";
    EXPECT_DOUBLE_EQ(inj[1].error[int(KpiParam::Width)], 0) << "length 2 < 3";
    EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::Heading)], 0) << "seen end-on";
    EXPECT_DOUBLE_EQ(inj[1].error[int(KpiParam::Heading)], 5) << "seen side-on (pi/2)";
    EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::Length)], f >= 3 ? 3 : 0) << "track age " << f;
  }
}

// Acceleration and truncation as the object loop defines them (qualify/objects/objects.h): acceleration
// the BEV norm of the truth's acceleration (the loop bins |a.head<2>()|, not the 3-D norm),
// truncation the object's share outside the FoV as it stands. tests/qualify/test_loop_features.cpp
// checks the same against the loop's own records.
TEST(KpiConditional, AccelerationIsTheBevNormAndTruncationTheObjectsShare) {
  KpiModel m = one_bin_car(0.0);
  auto& e = m.classes["Car"].errors;
  e[int(KpiParam::PositionAlong)].conditional = {"acceleration", {0, 4}, {0, 1}, {}};
  e[int(KpiParam::Length)].conditional = {"truncation", {0, 0.25, 0.75}, {0, 2, 3}, {}};
  Object a = car(1, {20, 0, -0.9}, {0, 0, 0}), b = car(2, {20, 5, -0.9}, {0, 0, 0});
  a.acceleration = {3, 0, 4};  // BEV 3 (bin 0); the 3-D norm 5 would be bin 1
  b.acceleration = {3, 4, 0};  // BEV 5 (bin 1)
  a.truncation = 0.2;
  b.truncation = 0.3;
  EXPECT_DOUBLE_EQ(conditional_feature("acceleration", a, 20, 0), 3);
  EXPECT_DOUBLE_EQ(conditional_feature("acceleration", b, 20, 0), 5);
  EXPECT_DOUBLE_EQ(conditional_feature("truncation", b, 20, 0), 0.3);
  KpiManager kpi(m, 1);
  std::vector<Object> out;
  kpi.apply({a, b}, out);
  const auto& inj = kpi.injections();
  EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::PositionAlong)], 0) << "BEV acceleration 3 < 4";
  EXPECT_DOUBLE_EQ(inj[1].error[int(KpiParam::PositionAlong)], 1) << "BEV acceleration 5 >= 4";
  EXPECT_DOUBLE_EQ(inj[0].error[int(KpiParam::Length)], 0) << "truncation 0.2 < 0.25";
  EXPECT_DOUBLE_EQ(inj[1].error[int(KpiParam::Length)], 2) << "truncation 0.3 in [0.25, 0.75)";
  // Both load as features of a model file; a non-finite input is refused naming the field.
  for (const char* f : {"acceleration", "truncation"}) {
    KpiModel w = default_kpi_model();
    w.classes["Car"].errors[0].conditional = {f, {0, 1}, {0, 0.1}, {}};
    EXPECT_NO_THROW(parse_kpi_model(kpi_model_to_json(w), "w.json")) << f;
  }
  b.truncation = std::nan("");
  try {
    kpi.apply({a, b}, out);
    ADD_FAILURE() << "NaN truncation accepted";
  } catch (const Error& err) {
    EXPECT_NE(std::string(err.what()).find("object 2: acceleration/truncation: must be finite"), std::string::npos)
        << err.what();
  }
}

TEST(KpiConditional, ZeroTermChangesNothingAndAbsentTermIsNotWritten) {
  KpiModel plain = default_kpi_model();
  KpiModel zero = plain;
  for (auto& [name, c] : zero.classes)
    for (auto& e : c.errors) e.conditional = {"speed", {0, 5}, {0, 0}, {1, 1}};
  KpiManager a(plain, 3), b(zero, 3);
  std::vector<Object> truth, oa, ob;
  for (int i = 0; i < 6; ++i) truth.push_back(car(i, {10.0 + 9 * i, 3.0 - i, -0.9}, {double(i), 0, 0}));
  for (int f = 0; f < 200; ++f) {
    a.apply(truth, oa);
    b.apply(truth, ob);
    ASSERT_EQ(oa.size(), ob.size());
    for (size_t i = 0; i < truth.size(); ++i)
      for (int p = 0; p < kNumKpiParams; ++p)
        ASSERT_EQ(a.injections()[i].error[p], b.injections()[i].error[p]) << "frame " << f;
  }
  EXPECT_EQ(kpi_model_to_json(plain).find("conditional"), std::string::npos);
  const std::string written = kpi_model_to_json(zero);
  EXPECT_NE(written.find("\"conditional\""), std::string::npos);
  EXPECT_EQ(kpi_model_to_json(parse_kpi_model(written, "zero.json")), written) << "round trip";
}

// Common random numbers: each track and purpose draws from its own stream, so a heavier-tailed
// innovation (more draws per sample) and a term on Car length leave every other parameter, every
// Pedestrian draw, the misses, flips, scores and false positives exactly as they were. With one
// shared stream the extra chi-squared draws shifted everything after them.
TEST(KpiConditional, ChangingOneClassesTargetLeavesEveryOtherDrawUnchanged) {
  const KpiModel plain = default_kpi_model();
  KpiModel changed = plain;
  ErrorModel& len = changed.classes["Car"].errors[int(KpiParam::Length)];
  len.innovation = {Innovation::Type::StudentT, 4, 0, 1};
  len.conditional = {"speed", {0, 2}, {0.1, -0.2}, {1, 1.5}};
  KpiManager a(plain, 9), b(changed, 9);
  std::vector<Object> truth, oa, ob;
  for (int i = 0; i < 6; ++i) {
    truth.push_back(car(i, {8.0 + 9 * i, 3.0 - i, -0.9}, {double(i), 0, 0}));
    if (i % 2) truth.back().cls = ObjectClass::Pedestrian;
  }
  int length_differs = 0;
  for (int f = 0; f < 300; ++f) {
    if (f == 150) truth.push_back(car(17, {12, -4, -0.9}, {1, 0, 0}));  // a track that starts later
    a.apply(truth, oa);
    b.apply(truth, ob);
    ASSERT_EQ(oa.size(), ob.size()) << "frame " << f;
    for (size_t i = 0; i < truth.size(); ++i) {
      const KpiInjection &x = a.injections()[i], &y = b.injections()[i];
      ASSERT_EQ(x.detected, y.detected) << "frame " << f;
      ASSERT_EQ(x.flipped, y.flipped) << "frame " << f;
      for (int p = 0; p < kNumKpiParams; ++p) {
        if (p == int(KpiParam::Length) && truth[i].cls == ObjectClass::Car) {
          length_differs += x.error[p] != y.error[p];
          continue;
        }
        ASSERT_EQ(x.error[p], y.error[p]) << "frame " << f << " object " << truth[i].id << " " << p;
      }
    }
    for (size_t k = 0; k < oa.size(); ++k) {
      ASSERT_EQ(oa[k].score, ob[k].score) << "frame " << f;
      if (oa[k].id <= -1000) {
        ASSERT_EQ(oa[k].position, ob[k].position) << "false positive, frame " << f;
      }
    }
  }
  EXPECT_GT(length_differs, 0) << "the changed target itself does change";
}

std::string parse_error(const nlohmann::json& j) {
  try {
    parse_kpi_model(j.dump(), "m.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(KpiConditional, BadTermsAreRefusedNamingFileAndField) {
  const auto good = nlohmann::json::parse(kpi_model_to_json(default_kpi_model()));
  const std::string f = "m.json: classes.Car.errors.position_along.conditional";
  auto with = [&](nlohmann::json term) {
    auto j = good;
    j["classes"]["Car"]["errors"]["position_along"]["conditional"] = term;
    return parse_error(j);
  };
  const nlohmann::json ok = {{"feature", "speed"}, {"edges", {0, 5}}, {"bias", {0, 0.5}}};
  EXPECT_EQ(with(ok), "(no error)");
  auto t = ok;
  t["feature"] = "class";  // in the loop's vocabulary, but the model conditions on it already
  EXPECT_NE(with(t).find(f + ".feature: must be one of the features"), std::string::npos) << with(t);
  t = ok;
  t.erase("feature");
  EXPECT_NE(with(t).find(f + ".feature: missing"), std::string::npos) << with(t);
  t = ok;
  t["bias"] = {0.5};
  EXPECT_NE(with(t).find(f + ".bias: must have 2 entries, got 1"), std::string::npos) << with(t);
  t = ok;
  t["edges"] = {5, 5};
  EXPECT_NE(with(t).find(f + ".edges[1]: must increase"), std::string::npos) << with(t);
  t = ok;
  t["edges"] = nlohmann::json::array();
  t["bias"] = nlohmann::json::array();
  EXPECT_NE(with(t).find(f + ".edges: must list at least one"), std::string::npos) << with(t);
  t = ok;
  t["scale"] = {1, 0};
  EXPECT_NE(with(t).find(f + ".scale[1]: must be in"), std::string::npos) << with(t);
  t = ok;
  t["bias"] = {0, "x"};
  EXPECT_NE(with(t).find(f + ".bias[1]: must be a number"), std::string::npos) << with(t);
  EXPECT_NE(with(42).find(f + ": must be an object"), std::string::npos) << with(42);
}

// --- The conditional term on detection probability (ClassModel::detection_conditional) ---

TEST(KpiDetectionConditional, AzimuthBiasSetsTheMissRateInItsBinAndTheProbabilityIsClampedOver4000Frames) {
  KpiModel m = one_bin_car(0.0);
  m.classes["Car"].detection_probability = {{0.9}};
  m.classes["Car"].miss_burst_mean = 1;
  // Azimuth bins: below 0 (right of the sensor) +0, [0, 0.5) -0.5, from 0.5 +0.5 (clamped to 1).
  m.classes["Car"].detection_conditional = {"azimuth", {-4, 0, 0.5}, {0, -0.5, 0.5}, {}};
  KpiManager kpi(m, 11);
  std::vector<Object> truth, out;
  for (int i = 0; i < 4; ++i) truth.push_back(car(i, {20, -2.0 - 3 * i, -0.9}, {0, 0, 0}));      // az < 0
  for (int i = 4; i < 8; ++i) truth.push_back(car(i, {30, 1.0 + 2 * (i - 4), -0.9}, {0, 0, 0}));  // az in (0, 0.5)
  truth.push_back(car(8, {5, 10, -0.9}, {0, 0, 0}));                                               // az 1.1
  const double expected[3] = {0.9, 0.4, 1.0};
  double k[3] = {0, 0, 0}, n[3] = {0, 0, 0};
  for (int f = 0; f < 4000; ++f) {
    kpi.apply(truth, out);
    for (const auto& inj : kpi.injections()) {
      const int b = inj.id < 4 ? 0 : inj.id < 8 ? 1 : 2;
      ASSERT_DOUBLE_EQ(inj.detection_probability, expected[b]) << "object " << inj.id;
      k[b] += inj.detected, ++n[b];
    }
  }
  for (int b = 0; b < 3; ++b)
    EXPECT_DOUBLE_EQ(kpi.detection_probability(truth[b == 0 ? 0 : b == 1 ? 4 : 8]), expected[b]) << "bin " << b;
  // 16000 Bernoulli draws per bin (miss runs of mean 1): standard error <= 0.004; tolerance 0.015.
  EXPECT_NEAR(k[0] / n[0], 0.9, 0.015) << "right of the sensor: the model's 0.9";
  EXPECT_NEAR(k[1] / n[1], 0.4, 0.015) << "the dropout bin: 0.9 - 0.5";
  EXPECT_EQ(k[2], n[2]) << "0.9 + 0.5 clamped to 1: never missed";
}

// A gain (scale) multiplies the cell's probability before the bias is added: 0.9 x 0.2 = 0.18 in
// the window, 0.9 outside; written and read back unchanged.
TEST(KpiDetectionConditional, ScaleMultipliesTheCellProbabilityBeforeTheBiasAndRoundTrips) {
  KpiModel m = one_bin_car(0.0);
  m.classes["Car"].detection_probability = {{0.9}};
  m.classes["Car"].detection_conditional = {"azimuth", {-4, 0, 0.5}, {0, 0, 0.05}, {1, 0.2, 0.5}};
  const KpiManager kpi(m, 3);
  EXPECT_DOUBLE_EQ(kpi.detection_probability(car(0, {20, -3, -0.9}, {0, 0, 0})), 0.9);         // az < 0
  EXPECT_NEAR(kpi.detection_probability(car(1, {30, 3, -0.9}, {0, 0, 0})), 0.18, 1e-12);        // az 0.1
  EXPECT_NEAR(kpi.detection_probability(car(2, {5, 10, -0.9}, {0, 0, 0})), 0.9 * 0.5 + 0.05, 1e-12);  // az 1.1
  const KpiModel back = parse_kpi_model(kpi_model_to_json(m), "m.json");
  EXPECT_EQ(back.classes.at("Car").detection_conditional.scale, (std::vector<double>{1, 0.2, 0.5}));
}

TEST(KpiDetectionConditional, AbsentTermIsNotWrittenAndZeroTermChangesNoDrawAndRoundTrips) {
  const KpiModel plain = default_kpi_model();
  KpiModel zero = plain;
  for (auto& [name, c] : zero.classes) c.detection_conditional = {"range", {0, 30}, {0, 0}, {}};
  KpiManager a(plain, 5), b(zero, 5);
  std::vector<Object> truth, oa, ob;
  for (int i = 0; i < 6; ++i) truth.push_back(car(i, {10.0 + 9 * i, 3.0 - i, -0.9}, {double(i), 0, 0}));
  for (int f = 0; f < 300; ++f) {
    a.apply(truth, oa);
    b.apply(truth, ob);
    ASSERT_EQ(oa.size(), ob.size()) << "frame " << f;
    for (size_t i = 0; i < truth.size(); ++i)
      ASSERT_EQ(a.injections()[i].detected, b.injections()[i].detected) << "frame " << f;
  }
  EXPECT_EQ(kpi_model_to_json(plain).find("detection_conditional"), std::string::npos);
  KpiModel with = plain;
  with.classes["Car"].detection_conditional = {"azimuth", {-4, 0.35, 1.2}, {0, -0.7, 0.05}, {}};
  const std::string written = kpi_model_to_json(with);
  EXPECT_NE(written.find("\"detection_conditional\""), std::string::npos);
  const KpiModel back = parse_kpi_model(written, "with.json");
  const ConditionalTerm& ct = back.classes.at("Car").detection_conditional;
  EXPECT_EQ(ct.feature, "azimuth");
  EXPECT_EQ(ct.edges, (std::vector<double>{-4, 0.35, 1.2}));
  EXPECT_EQ(ct.bias, (std::vector<double>{0, -0.7, 0.05}));
  EXPECT_TRUE(ct.scale.empty());
  EXPECT_FALSE(back.classes.at("Pedestrian").detection_conditional.present());
  EXPECT_EQ(kpi_model_to_json(back), written) << "round trip";
}

TEST(KpiDetectionConditional, ShippedModelLoadsWithoutTheTermAndIsRewrittenByteIdentical) {
  const std::filesystem::path shipped = lidarsim::testing::source_dir() / "data/models/kpi_pointrcnn.json";
  std::ifstream in(shipped);
  ASSERT_TRUE(in) << shipped;
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const KpiModel m = parse_kpi_model(text, shipped.string());
  for (const auto& [name, c] : m.classes) EXPECT_FALSE(c.detection_conditional.present()) << name;
  EXPECT_EQ(kpi_model_to_json(m), text);
}

TEST(KpiDetectionConditional, BadTermsAreOneErrorNamingFileAndPath) {
  const auto good = nlohmann::json::parse(kpi_model_to_json(default_kpi_model()));
  const std::string f = "m.json: classes.Car.detection_conditional";
  auto with = [&](nlohmann::json term) {
    auto j = good;
    j["classes"]["Car"]["detection_conditional"] = term;
    return parse_error(j);
  };
  const nlohmann::json ok = {{"feature", "azimuth"}, {"edges", {-4, 0.35}}, {"bias", {0, -0.7}}};
  EXPECT_EQ(with(ok), "(no error)");
  auto t = ok;
  t["feature"] = "occlusion";  // in the loop's vocabulary, but the KPI manager cannot compute it
  EXPECT_NE(with(t).find(f + ".feature: must be one of the features"), std::string::npos) << with(t);
  t = ok;
  t["edges"] = {0.35, -4};
  EXPECT_NE(with(t).find(f + ".edges[1]: must increase"), std::string::npos) << with(t);
  t = ok;
  t["bias"] = {0, nullptr};  // how a NaN bias comes out of a JSON writer
  EXPECT_NE(with(t).find(f + ".bias[1]: must be a number"), std::string::npos) << with(t);
  t = ok;
  t["bias"] = {0, -1.5};
  EXPECT_NE(with(t).find(f + ".bias[1]: must be in [-1, 1]"), std::string::npos) << with(t);
  t = ok;
  t["scale"] = {1, 0.2};  // a gain on the cell's probability
  EXPECT_EQ(with(t), "(no error)");
  t["scale"] = {1, -0.2};
  EXPECT_NE(with(t).find(f + ".scale[1]: must be in [0, "), std::string::npos) << with(t);
  t = ok;
  t["bias"] = {0};
  EXPECT_NE(with(t).find(f + ".bias: must have 2 entries, got 1"), std::string::npos) << with(t);
  // A model built in code (not parsed) with a NaN bias is refused by validate() alike.
  KpiModel m = default_kpi_model();
  m.classes["Car"].detection_conditional = {"azimuth", {-4, 0.35}, {0, std::nan("")}, {}};
  try {
    m.validate("code.json");
    ADD_FAILURE() << "NaN bias accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("code.json: classes.Car.detection_conditional.bias[1]: must be a finite number"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace lidarsim::sensor
