// Scenario and KPI model files with impossible or unbounded content: one Error naming the field,
// before anything large is allocated.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>

#include "common/error.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;
using json = nlohmann::json;

namespace {

json load(const std::string& relative) {
  std::ifstream in(lidarsim::testing::source_dir() / relative);
  return json::parse(std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()), nullptr, true,
                     true);
}

std::string scenario_error(const json& j) {
  try {
    sensor::parse_scenario(j.dump(), "s.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

std::string kpi_error(const json& j) {
  try {
    sensor::parse_kpi_model(j.dump(), "kpi.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(InputReliability, KpiModelFieldsOfTheWrongTypeAreAnError) {
  json j = load("data/models/kpi_pointrcnn.json");
  ASSERT_EQ(kpi_error(j), "");
  j["controller"] = "fast";
  EXPECT_NE(kpi_error(j).find("controller"), std::string::npos);
}

TEST(InputReliability, ScenarioSizesBeyondTheLimitsAreAnErrorNotAnAllocation) {
  const json base = load("data/scenarios/demo_urban.json");
  ASSERT_EQ(scenario_error(base), "");
  json wide = base;
  wide["sensor"]["columns"] = 100000000;
  EXPECT_NE(scenario_error(wide).find("sensor.columns"), std::string::npos) << scenario_error(wide);
  json many = base;
  ASSERT_FALSE(many["objects"].empty());
  const json one = many["objects"][0];
  for (int i = 0; i < 10000; ++i) {
    json copy = one;
    copy["id"] = 100000 + i;
    many["objects"].push_back(copy);
  }
  EXPECT_NE(scenario_error(many).find("objects"), std::string::npos);
  json lasting = base;
  lasting["duration"] = 1e9;
  EXPECT_NE(scenario_error(lasting).find("duration"), std::string::npos);
}
