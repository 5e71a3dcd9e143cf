// `lidar-infer sim` through its command line: it runs a few frames and writes the summary, writes
// every n-th frame through the writer thread, and on a bad input names the file (and the field)
// in one error line and exits non-zero.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tests/e2e/sim_pipeline_fixture.h"

namespace lidarsim {
namespace {

namespace fs = std::filesystem;
using sim_test::read_text;
using sim_test::SimPipelineTest;

TEST_F(SimPipelineTest, CliRunsAFewFramesAndWritesTheSummary) {
  std::string err;
  const fs::path out = dir_ / "cli";
  const int rc = run_cli("--model " + checkpoint().string() + " --frames 2 --format ply --quiet --out " + out.string(), err);
  ASSERT_EQ(rc, 0) << err;
  EXPECT_TRUE(fs::exists(out / "cloud_0001.ply"));
  EXPECT_TRUE(fs::exists(out / "summary.md"));
  EXPECT_EQ(nlohmann::json::parse(read_text(out / "summary.json"))["frames"], 2);
}

TEST_F(SimPipelineTest, CliEveryWritesOnlyEveryNthFrameThroughTheWriterThread) {
  std::string err;
  const fs::path out = dir_ / "every";
  const int rc = run_cli("--model " + checkpoint().string() + " --frames 5 --every 2 --no-images --quiet --out " +
                             out.string(), err);
  ASSERT_EQ(rc, 0) << err;
  for (int k = 0; k < 5; ++k) {
    char name[32];
    std::snprintf(name, sizeof name, "cloud_%04d.pcd", k);
    EXPECT_EQ(fs::exists(out / name), k % 2 == 0) << name;
  }
  const auto summary = nlohmann::json::parse(read_text(out / "summary.json"));
  EXPECT_EQ(summary["frames"], 5);
  EXPECT_EQ(summary["frames_without_intensity"], 2) << "the UNet runs on the written frames 0, 2, 4 only";
}

// One line on stderr, naming the file, and a non-zero exit.
void expect_one_error_line(int rc, const std::string& err, const std::string& file) {
  EXPECT_NE(rc, 0);
  EXPECT_EQ(err.rfind("error: ", 0), 0u) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_NE(err.find(file), std::string::npos) << err;
}

TEST_F(SimPipelineTest, CliMissingScenarioNamesTheFile) {
  std::string err;
  const std::string missing = (dir_ / "no_such_scenario.json").string();
  const int rc = run_cli("--scenario " + missing + " --model " + checkpoint().string() + " --out " + (dir_ / "x").string(), err);
  expect_one_error_line(rc, err, missing);
}

TEST_F(SimPipelineTest, CliUnreadableModelNamesTheFile) {
  std::string err;
  const fs::path bad = dir_ / "not_a_checkpoint.h5";
  std::ofstream(bad) << "this is not HDF5\n";
  const int rc = run_cli("--model " + bad.string() + " --out " + (dir_ / "x").string(), err);
  expect_one_error_line(rc, err, bad.string());
}

TEST_F(SimPipelineTest, CliBadKpiModelNamesTheFile) {
  std::string err;
  const fs::path bad = dir_ / "bad_kpi.json";
  std::ofstream(bad) << "{\"range_bin_edges\": [0, 20], \"classes\": 3}\n";
  const int rc = run_cli("--kpi " + bad.string() + " --model " + checkpoint().string() + " --out " + (dir_ / "x").string(), err);
  expect_one_error_line(rc, err, bad.string());
}

// The bundled scenario with one field broken, through the CLI: the error names file and field.
TEST_F(SimPipelineTest, CliBadScenarioFieldsNameTheFileAndTheField) {
  const auto base = nlohmann::json::parse(read_text(scenario()));
  struct Case {
    const char* name;
    const char* field;
    void (*edit)(nlohmann::json&);
  };
  const Case cases[] = {
      {"negative_size", "objects[0].size[0]", [](nlohmann::json& j) { j["objects"][0]["size"][0] = -4.5; }},
      {"unknown_class", "objects[2].class", [](nlohmann::json& j) { j["objects"][2]["class"] = "Spaceship"; }},
      {"missing_field", "sensor", [](nlohmann::json& j) { j.erase("sensor"); }},
  };
  for (const auto& c : cases) {
    nlohmann::json j = base;
    c.edit(j);
    const fs::path file = dir_ / (std::string(c.name) + ".json");
    std::ofstream(file) << j.dump();
    std::string err;
    const int rc = run_cli("--scenario " + file.string() + " --model " + checkpoint().string() + " --out " + (dir_ / "x").string(), err);
    expect_one_error_line(rc, err, file.string());
    EXPECT_NE(err.find(c.field), std::string::npos) << c.name << ": " << err;
  }
  // Python's json writes NaN as a bare token: the reader must refuse it, naming the path.
  std::string text = base.dump();
  const std::string key = "\"duration\":";
  const auto at = text.find(key);
  ASSERT_NE(at, std::string::npos);
  const auto end = text.find(',', at);
  text.replace(at + key.size(), end - at - key.size(), "NaN");
  const fs::path nan_file = dir_ / "nan.json";
  std::ofstream(nan_file) << text;
  std::string err;
  const int rc = run_cli("--scenario " + nan_file.string() + " --model " + checkpoint().string() + " --out " + (dir_ / "x").string(), err);
  expect_one_error_line(rc, err, nan_file.string());
}

}  // namespace
}  // namespace lidarsim
