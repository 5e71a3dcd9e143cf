#pragma once
// The fixture of the simulation pipeline's end-to-end tests (test_sim_pipeline.cpp,
// test_sim_cli.cpp): the bundled demo scenario and KPI model, and a tiny untrained intensity UNet
// (base 4, depth 2) written once per suite. Named (not anonymous) so both files share one suite.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "infer/sim_pipeline.h"
#include "tests/support/shared_data.h"

namespace lidarsim::sim_test {

namespace fs = std::filesystem;

inline std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class SimPipelineTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("lidarsim_test_sim_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    infer::write_untrained_checkpoint(checkpoint(), 4, 2, 7, pgm::BeamLayout::hdl64e());
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }
  static fs::path checkpoint() { return dir_ / "tiny_unet.h5"; }
  static fs::path scenario() { return testing::source_dir() / "data/scenarios/demo_urban.json"; }
  static fs::path kpi() { return testing::source_dir() / "data/models/kpi_pointrcnn.json"; }
  // objects_only: the object-level model without PCL generator and UNet (fast, same object list).
  static infer::SimPipeline make(std::uint64_t seed = 1, bool objects_only = false) {
    infer::SimOptions o;
    o.seed = seed;
    o.point_cloud = !objects_only;
    return infer::SimPipeline::from_files(scenario(), kpi(), checkpoint(), o);
  }
  static int run_cli(const std::string& args, std::string& err) {
    const fs::path exe = testing::binary_dir() / "infer/lidar-infer";
    const fs::path err_file = dir_ / "stderr.txt";
    const int rc = std::system((exe.string() + " sim " + args + " >/dev/null 2>" + err_file.string()).c_str());
    err = read_text(err_file);
    return rc;
  }
  static inline fs::path dir_;
};

}  // namespace lidarsim::sim_test
