// A conditional term on an error whose bias is relative (ConditionalTerm::relative_to): the bin's
// bias times a feature of the same object, e.g. a length error that is a share of the object's own
// length. Applied by the KPI manager, written and read back by the model file, refused with one
// error naming the field where it cannot apply; a model without it is as before.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "common/error.h"
#include "sensor/kpi_manager.h"
#include "sensor/kpi_model.h"

namespace lidarsim::sensor {
namespace {

// Car only, one range and visibility bin, no noise, misses, flips or false positives: the
// injected error is mean + the term's bias exactly.
KpiModel relterm_noiseless_car() {
  KpiModel m = default_kpi_model();
  m.range_bin_edges = {0};
  m.visibility_bin_edges = {0};
  ClassModel c = m.classes["Car"];
  for (auto& e : c.errors) {
    e.mean = {0};
    e.sigma = {0};
    e.visibility_std_scale = {1};
    e.ar1 = 0;
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

Object relterm_car(int id, double x, double y, double heading, double length, double width) {
  Object o;
  o.id = id;
  o.position = {x, y, -0.9};
  o.velocity = {0, 0, 0};
  o.heading = heading;
  o.size = {length, width, 1.5};
  return o;
}

// Length short by 20 % of the object's own length seen end-on, 5 % side-on: the same bins give
// a 5 m car 1.0 m and a 3 m car 0.6 m end-on. An absolute term would give both the same.
TEST(KpiRelativeTerm, BiasIsTheBinsShareTimesTheObjectsOwnSize) {
  KpiModel m = relterm_noiseless_car();
  const int len = int(KpiParam::Length), wid = int(KpiParam::Width);
  m.classes["Car"].errors[len].mean = {0.1};
  ConditionalTerm ct{"heading_to_line_of_sight", {0, 0.8}, {-0.2, -0.05}, {}};
  ct.relative_to = "size";
  m.classes["Car"].errors[len].conditional = ct;
  ConditionalTerm cw{"heading_to_line_of_sight", {0, 0.8}, {0.1, 0.1}, {}};
  cw.relative_to = "box_width";
  m.classes["Car"].errors[wid].conditional = cw;
  KpiManager kpi(m, 5);
  // Ids 1, 2 at (20, 0) heading +x: seen end-on (0 rad). Id 3 at (0, 20) heading +x: side-on.
  const std::vector<Object> truth = {relterm_car(1, 20, 0, 0, 5, 2), relterm_car(2, 20, 0.5, 0, 3, 1.5),
                                     relterm_car(3, 0, 20, 0, 4, 1.8)};
  std::vector<Object> out;
  for (int f = 0; f < 3; ++f) {
    kpi.apply(truth, out);
    const auto& inj = kpi.injections();
    EXPECT_NEAR(inj[0].error[len], 0.1 - 0.2 * 5, 1e-9) << "5 m car end-on";
    EXPECT_NEAR(inj[1].error[len], 0.1 - 0.2 * 3, 1e-9) << "3 m car end-on";
    EXPECT_NEAR(inj[2].error[len], 0.1 - 0.05 * 4, 1e-9) << "4 m car side-on";
    EXPECT_NEAR(inj[0].error[wid], 0.1 * 2, 1e-9) << "width relative to the object's own width";
    EXPECT_NEAR(inj[2].error[wid], 0.1 * 1.8, 1e-9);
  }
}

TEST(KpiRelativeTerm, RoundTripsAndAModelWithoutItWritesNoKey) {
  KpiModel m = default_kpi_model();
  EXPECT_EQ(kpi_model_to_json(m).find("relative_to"), std::string::npos);
  ConditionalTerm ct{"heading_to_line_of_sight", {0, 0.8}, {-0.2, -0.05}, {}};
  ct.relative_to = "size";
  m.classes["Car"].errors[int(KpiParam::Length)].conditional = ct;
  const std::string written = kpi_model_to_json(m);
  EXPECT_NE(written.find("\"relative_to\": \"size\""), std::string::npos) << written.substr(0, 200);
  const KpiModel back = parse_kpi_model(written, "rel.json");
  EXPECT_EQ(back.classes.at("Car").errors[int(KpiParam::Length)].conditional.relative_to, "size");
  EXPECT_EQ(kpi_model_to_json(back), written);
}

std::string relterm_parse_error(const nlohmann::json& j) {
  try {
    parse_kpi_model(j.dump(), "m.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(KpiRelativeTerm, BadRelativeToIsOneErrorNamingFileAndField) {
  const auto good = nlohmann::json::parse(kpi_model_to_json(default_kpi_model()));
  const nlohmann::json ok = {{"feature", "speed"}, {"edges", {0, 5}}, {"bias", {0, 0.1}}, {"relative_to", "size"}};
  auto on_length = [&](nlohmann::json term) {
    auto j = good;
    j["classes"]["Car"]["errors"]["length"]["conditional"] = term;
    return relterm_parse_error(j);
  };
  EXPECT_EQ(on_length(ok), "(no error)");
  const std::string f = "m.json: classes.Car.errors.length.conditional.relative_to";
  auto t = ok;
  t["relative_to"] = "wheelbase";
  EXPECT_NE(on_length(t).find(f + ": must be one of the features"), std::string::npos) << on_length(t);
  t["relative_to"] = 3;
  EXPECT_NE(on_length(t).find(f + ": must be a feature name"), std::string::npos) << on_length(t);
  auto j = good;
  j["classes"]["Car"]["detection_conditional"] = ok;
  EXPECT_NE(relterm_parse_error(j).find("m.json: classes.Car.detection_conditional.relative_to: is for error terms only"),
            std::string::npos)
      << relterm_parse_error(j);
}

}  // namespace
}  // namespace lidarsim::sensor
