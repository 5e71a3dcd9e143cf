// lidar-qualify end to end: the loop on reference-sensor data writes the documented keys; bad
// input (missing or mismatched files in DIR) gives one clear "error: ..." line and a non-zero
// exit; and, when the measured data are present, both loops run on them.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <string>

#include <nlohmann/json.hpp>

#include "data/reference_sensor.h"
#include "infer/intensity_model.h"
#include "sensor/kpi_model.h"
#include "tests/support/sanitizer.h"
#include "tests/support/shared_data.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

struct CliRun {
  int code = -1;
  std::string out;  // stdout + stderr
};

CliRun run(const std::string& args) {
  const std::string cmd = (lidarsim::testing::binary_dir() / "qualify" / "lidar-qualify").string() + " " + args + " 2>&1";
  CliRun r;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf{};
  while (fgets(buf.data(), buf.size(), p)) r.out += buf.data();
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class QualifyCli : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("lidarsim_qcli_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path tracking(int sequences = 2) {
    data::ReferenceTrackingOptions o;
    o.frames = 60;
    o.sequences = sequences;
    data::write_reference_tracking(dir_ / "kt", o);
    return dir_ / "kt";
  }
  fs::path scans() {
    data::ReferenceScanOptions o;
    o.scans = 2;
    o.columns = 512;
    data::write_reference_semantickitti(dir_ / "sk", o);
    return dir_ / "sk";
  }
  fs::path dir_;
};

// One line starting with "error: " that mentions `what`, and a non-zero exit.
void expect_one_error(const CliRun& r, const std::string& what) {
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_EQ(r.out.rfind("error: ", 0), 0u) << r.out;
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
  EXPECT_NE(r.out.find(what), std::string::npos) << "expected \"" << what << "\" in: " << r.out;
}

void expect_loop_keys(const fs::path& report, const std::string& domain) {
  std::ifstream in(report);
  ASSERT_TRUE(in) << report;
  const auto j = nlohmann::json::parse(in);
  EXPECT_EQ(j["domain"], domain);
  EXPECT_TRUE(j["metric"].is_string());
  EXPECT_TRUE(j["before"].is_number());
  EXPECT_TRUE(j["after"].is_number());
  ASSERT_TRUE(j["ranking"].is_array());
  ASSERT_FALSE(j["ranking"].empty());
  // Best first; the object loop puts the forms that pass its ranking's tests before those that do not
  // (a ruled-out form must not hide one that passes), each group by score.
  for (size_t i = 1; i < j["ranking"].size(); ++i) {
    const auto &a = j["ranking"][i - 1], &b = j["ranking"][i];
    const bool pa = a.value("passes_ranking_tests", true), pb = b.value("passes_ranking_tests", true);
    EXPECT_TRUE(pa || !pb) << "a form that passes after one that does not, at " << i;
    if (pa == pb) EXPECT_GE(a["score"].get<double>(), b["score"].get<double>()) << "best first, at " << i;
  }
  EXPECT_TRUE(j.contains("added_effect"));
  EXPECT_LE(j["after"].get<double>(), j["before"].get<double>() + 1e-12);
}

}  // namespace

TEST_F(QualifyCli, HelpExitsZeroAndUnknownCommandFails) {
  EXPECT_EQ(run("--help").code, 0);
  expect_one_error(run("frobnicate"), "unknown command");
  expect_one_error(run("loop sideways --report x.json"), "unknown domain");
}

TEST_F(QualifyCli, LoopObjectsOnReferenceDataWritesTheDocumentedKeys) {
  const fs::path kt = tracking();
  const CliRun r = run("loop objects --kitti-tracking " + kt.string() + " --report " + (dir_ / "r.json").string() +
                       " --out-model " + (dir_ / "m.json").string());
  ASSERT_EQ(r.code, 0) << r.out;
  expect_loop_keys(dir_ / "r.json", "objects");
  // --out-model: the refitted KPI model is written and loads (validated) as a KPI model file.
  EXPECT_NO_THROW(lidarsim::sensor::load_kpi_model(dir_ / "m.json"));
  std::ifstream in(dir_ / "r.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_TRUE(j.contains("after_simulated")) << j.dump().substr(0, 300);
}

TEST_F(QualifyCli, LoopIntensityOnReferenceDataWritesTheDocumentedKeys) {
  const fs::path sk = scans();
  // The UNet loop, briefly trained: the keys, and the model it ends with loads for inference. Under
  // the sanitizers (20x slower on training) 8 steps run the same code paths.
  const std::string steps = std::to_string(lidarsim::testing::unless_sanitized(60, 8));
  const CliRun r = run("loop intensity --semantickitti " + sk.string() + " --report " + (dir_ / "r.json").string() +
                       " --steps " + steps + " --seeds 1 --quiet --out-model " + (dir_ / "ck.h5").string());
  ASSERT_EQ(r.code, 0) << r.out;
  expect_loop_keys(dir_ / "r.json", "intensity");
  const auto model = infer::IntensityModel::load(dir_ / "ck.h5");
  std::ifstream in(dir_ / "r.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_EQ(j["seeds_before"].size(), 1u);
  EXPECT_TRUE(fs::exists(dir_ / "r.md"));
}

TEST_F(QualifyCli, UnknownIntensityBaseModelIsOneClearError) {
  const fs::path sk = scans();
  expect_one_error(run("loop intensity --semantickitti " + sk.string() + " --report r.json --base forest"), "forest");
}

TEST_F(QualifyCli, UnknownTermShrinkIsOneClearErrorAndTheShrinkModesRun) {
  const fs::path kt = tracking();
  expect_one_error(run("loop objects --kitti-tracking " + kt.string() + " --report r.json --term-shrink sometimes"),
                   "--term-shrink");
  // The sixth pass's options (qualify/README.md): the loop runs and reports the shrink factors.
  const CliRun r = run("loop objects --kitti-tracking " + kt.string() + " --report " + (dir_ / "r.json").string() +
                       " --term-shrink pooled --pool-track-spread");
  ASSERT_EQ(r.code, 0) << r.out;
  expect_loop_keys(dir_ / "r.json", "objects");
  std::ifstream in(dir_ / "r.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_TRUE(j.contains("track_spread_pooling")) << j.dump().substr(0, 300);
  for (const auto& e : j["added_effects"]) EXPECT_TRUE(e["shrink_per_fold"].is_array()) << e.dump().substr(0, 300);
}

TEST_F(QualifyCli, MissingTrackingFolderIsOneClearError) {
  expect_one_error(run("loop objects --kitti-tracking " + (dir_ / "nope").string() + " --report r.json"), "nope");
}

TEST_F(QualifyCli, MissingCalibFolderIsNamed) {
  const fs::path kt = tracking();
  fs::remove_all(kt / "calib");
  expect_one_error(run("loop objects --kitti-tracking " + kt.string() + " --report r.json"), "calib");
}

TEST_F(QualifyCli, LabelsWithoutTheirCalibFileNameTheFile) {
  const fs::path kt = tracking();
  fs::remove(kt / "calib" / "0001.txt");
  expect_one_error(run("loop objects --kitti-tracking " + kt.string() + " --report r.json"), "0001.txt");
}

TEST_F(QualifyCli, LabelsWithoutDetectionsNameTheSequence) {
  const fs::path kt = tracking();
  for (const char* c : {"Car", "Pedestrian", "Cyclist"})
    fs::remove(kt / "detection" / (std::string("pointrcnn_") + c + "_val") / "0001.txt");
  expect_one_error(run("loop objects --kitti-tracking " + kt.string() + " --report r.json"), "0001");
}

TEST_F(QualifyCli, OneSequenceIsTooFewForTheLoop) {
  const fs::path kt = tracking();
  fs::remove(kt / "label_02" / "0001.txt");
  expect_one_error(run("loop objects --kitti-tracking " + kt.string() + " --report r.json"), "at least 2");
}

TEST_F(QualifyCli, MalformedLabelLineIsNamed) {
  const fs::path kt = tracking();
  std::ofstream(kt / "label_02" / "0000.txt", std::ios::app) << "3 7 Car not-a-number\n";
  expect_one_error(run("loop objects --kitti-tracking " + kt.string() + " --report r.json"), "0000.txt");
}

TEST_F(QualifyCli, LabelCountNotMatchingThePointsIsNamed) {
  const fs::path sk = scans();
  fs::resize_file(sk / "sequences" / "00" / "labels" / "000001.label", 400);
  expect_one_error(run("loop intensity --semantickitti " + sk.string() + " --report r.json"), "000001.label");
}

TEST_F(QualifyCli, SemanticKittiFolderWithoutScansIsOneClearError) {
  fs::create_directories(dir_ / "empty");
  expect_one_error(run("loop intensity --semantickitti " + (dir_ / "empty").string() + " --report r.json"), "empty");
}

TEST_F(QualifyCli, ObjectsNeedsItsModelFile) {
  const fs::path kt = tracking();
  expect_one_error(run("objects --kitti-tracking " + kt.string() + " --model " + (dir_ / "m.json").string() +
                       " --out " + (dir_ / "out").string()),
                   "m.json");
}

TEST_F(QualifyCli, ObjectsRefusesZeroHeldOutSeeds) {
  const fs::path kt = tracking();
  const fs::path model = lidarsim::testing::source_dir() / "data" / "models" / "kpi_pointrcnn.json";
  expect_one_error(run("objects --held-out-seeds 0 --kitti-tracking " + kt.string() + " --model " + model.string() +
                       " --out " + (dir_ / "out").string()),
                   "--held-out-seeds");
}

TEST_F(QualifyCli, ObjectsReportOnReferenceDataHasOverallSimilarityAndCeiling) {
  const fs::path kt = tracking();
  const fs::path model = lidarsim::testing::source_dir() / "data" / "models" / "kpi_pointrcnn.json";
  const CliRun r = run("objects --held-out-seeds 8 --kitti-tracking " + kt.string() + " --model " + model.string() +
                       " --out " + (dir_ / "out").string());
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream in(dir_ / "out" / "report.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_GT(j["overall"]["kpis"].get<int>(), 0);
  EXPECT_GE(j["overall"]["similarity"].get<double>(), 0.0);
  EXPECT_LE(j["overall"]["similarity"].get<double>(), 1.0);
  EXPECT_TRUE(fs::exists(dir_ / "out" / "report.md"));
  // Held out: every KPI row says model - iid with its interval over held-out tracks.
  const auto& held = j["held_out_errors"];
  ASSERT_TRUE(held.contains("kpis")) << held.dump().substr(0, 300);
  int sure = 0;
  for (const auto& row : held["kpis"]) {
    const auto& iv = row["model_minus_iid_interval95"];
    EXPECT_LT(iv[0].get<double>(), iv[1].get<double>()) << row.dump();
    EXPECT_GE(row["held_out_tracks"].get<int>(), 2) << row.dump();
    EXPECT_NEAR(row["model_minus_iid"].get<double>(), row["model"].get<double>() - row["gaussian_iid"].get<double>(), 1e-12);
    sure += iv[0].get<double>() > 0 || iv[1].get<double>() < 0;
  }
  EXPECT_EQ(sure, held["kpis_model_surely_better_than_iid"].get<int>() + held["kpis_model_surely_worse_than_iid"].get<int>());
  EXPECT_EQ(held["plot"], "held_out_vs_iid.png");
  EXPECT_TRUE(fs::exists(dir_ / "out" / "held_out_vs_iid.png"));
}

TEST_F(QualifyCli, ObjectsNestedRunsTheLoopOnEachOuterFoldsFitSequencesOnly) {
  const fs::path kt = tracking(4);  // two per outer fold: the loop's inner split needs two
  const fs::path model = lidarsim::testing::source_dir() / "data" / "models" / "kpi_pointrcnn.json";
  const CliRun r = run("objects --nested --held-out-seeds 8 --kitti-tracking " + kt.string() + " --model " + model.string() + " --out " +
                       (dir_ / "out").string());
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream in(dir_ / "out" / "report.json");
  const auto held = nlohmann::json::parse(in)["held_out_errors"];
  ASSERT_TRUE(held.contains("nested")) << held.dump().substr(0, 300);
  const auto& folds = held["nested"]["folds"];
  ASSERT_EQ(folds.size(), 2u);
  // Each loop saw only its outer fold's fit sequences: disjoint from what it is judged on, and
  // the two folds' fit sets swap roles.
  for (const auto& f : folds)
    for (const auto& s : f["fit"])
      EXPECT_EQ(std::count(f["judge"].begin(), f["judge"].end(), s), 0) << f.dump();
  EXPECT_EQ(folds[0]["fit"], folds[1]["judge"]);
  EXPECT_EQ(folds[1]["fit"], folds[0]["judge"]);
  for (int k = 1; k <= 2; ++k)
    EXPECT_NO_THROW(lidarsim::sensor::load_kpi_model(dir_ / "out" / ("nested_fold_" + std::to_string(k) + "_model.json")));
  for (const auto& row : held["kpis"]) {
    EXPECT_GE(row["model_nested"].get<double>(), 0.0);
    EXPECT_LE(row["model_nested"].get<double>(), 1.0);
  }
}

// The small version of KpiCalibrationCampaign.ShippedDefaultModelIsWhatTheObjectLoopWritesWithTermsKeptPerClass
// (256 seeds, minutes): with 4 seeds in the distribution check the loop keeps more terms per class
// than with 256, but what comes before that check does not depend on the seeds (2, 8 and 16 seeds
// write the same parts checked here; each seed costs ~0.4 s of the ~18 s). So the loop must add the
// same feature per target as the shipped model has, and write, for every class, the same width
// error model (lidar-calibrate's fit plus the loop's box_width term), the same Pedestrian length
// term and the same detection, clutter and size statistics as data/models/kpi_pointrcnn.json.
TEST(QualifyRealDataStatistical, ObjectLoopOnTheMeasuredDataRefitsTheShippedTerms) {
  LIDARSIM_REQUIRE_SHARED_DATA(kt, "kitti-tracking-gt-pointrcnn");
  const fs::path out = fs::temp_directory_path() / ("lidarsim_qcli_real_" + std::to_string(::getpid()));
  fs::create_directories(out);
  const CliRun a = run("loop objects --held-out-seeds 4 --kitti-tracking " + kt.string() + " --report " +
                       (out / "o.json").string() + " --out-model " + (out / "m.json").string());
  ASSERT_EQ(a.code, 0) << a.out;
  expect_loop_keys(out / "o.json", "objects");
  std::ifstream report_in(out / "o.json");
  const auto report = nlohmann::json::parse(report_in);
  std::map<std::string, std::string> added;
  for (const auto& e : report["added_effects"]) added[e["target"].get<std::string>()] = e["feature"].get<std::string>();
  EXPECT_EQ(added["width"], "box_width") << report["added_effects"].dump();
  EXPECT_EQ(added["length"], "size") << report["added_effects"].dump();
  std::ifstream shipped_in(lidarsim::testing::source_dir() / "data/models/kpi_pointrcnn.json"), written_in(out / "m.json");
  const auto shipped = nlohmann::json::parse(shipped_in), written = nlohmann::json::parse(written_in);
  for (const char* c : {"Car", "Pedestrian", "Cyclist"}) {
    const auto& s = shipped["classes"][c];
    const auto& w = written["classes"][c];
    EXPECT_EQ(w["errors"]["width"], s["errors"]["width"]) << c;
    for (const auto& [key, value] : s.items()) {
      if (key == "errors") continue;
      EXPECT_EQ(w[key], value) << c << " " << key;
    }
  }
  EXPECT_EQ(written["classes"]["Pedestrian"]["errors"]["length"]["conditional"],
            shipped["classes"]["Pedestrian"]["errors"]["length"]["conditional"]);
  fs::remove_all(out);
}

// The lookup base (about a second); the UNet loop on these scans takes minutes (docs/loop.md).
TEST(QualifyRealDataStatistical, IntensityLoopOnTheMeasuredScansStartsFromTheClassRangeLookup) {
  LIDARSIM_REQUIRE_SHARED_DATA(sk, "semantickitti-seq00-sample");
  const fs::path out = fs::temp_directory_path() / ("lidarsim_qcli_real_int_" + std::to_string(::getpid()));
  fs::create_directories(out);
  const CliRun b =
      run("loop intensity --base lookup --folds 1 --semantickitti " + sk.string() + " --report " + (out / "i.json").string());
  ASSERT_EQ(b.code, 0) << b.out;
  expect_loop_keys(out / "i.json", "intensity");
  // The base model of the intensity loop is the class x range lookup, on the guarded split's cells
  // (--folds 1: its two regions as they are, not rotated):
  // `lidar-data baselines` measures 0.0851 on the same cells (0.082 on the old, leaking split).
  std::ifstream in(out / "i.json");
  EXPECT_NEAR(nlohmann::json::parse(in)["before"].get<double>(), 0.0851, 0.0005);
  fs::remove_all(out);
}

// The loop on the spread of intensity: its report (JSON and Markdown) on the reference scans, and
// one clear error for each bad input.
TEST_F(QualifyCli, LoopIntensitySpreadWritesItsReportAndRefusesBadInput) {
  const fs::path sk = scans();
  const CliRun a = run("loop intensity-spread --semantickitti " + sk.string() + " --report " + (dir_ / "s.json").string());
  ASSERT_EQ(a.code, 0) << a.out;
  std::ifstream in(dir_ / "s.json");
  const auto report = nlohmann::json::parse(in);
  ASSERT_EQ(report["rounds"].size(), 1u);
  const auto& round = report["rounds"][0];
  EXPECT_GT(round["scored"].get<long>(), 1000);
  EXPECT_GE(round["candidates"].size(), 13u);
  for (const auto& c : round["candidates"]) EXPECT_FALSE(c["reason"].get<std::string>().empty()) << c.dump();
  std::ifstream md(dir_ / "s.md");
  const std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text.rfind("# Closed loop: intensity spread", 0), 0u) << text.substr(0, 80);
  expect_one_error(run("loop intensity-spread --semantickitti " + sk.string()), "--report");
  expect_one_error(run("loop intensity-spread --semantickitti " + sk.string() + " --report " + (dir_ / "t.json").string() +
                       " --base-terms lasers"),
                   "--base-terms");
  expect_one_error(run("loop intensity-spread --semantickitti " + (dir_ / "missing").string() + " --report " +
                       (dir_ / "t.json").string()),
                   "missing");
}
