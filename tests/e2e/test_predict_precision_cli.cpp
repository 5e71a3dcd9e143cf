// lidar-infer predict --precision: bf16 inference (nn/precision.h) on the bundled scan and model
// keeps the MAE within the gate (0.0005) of fp32, and a bad value is one line.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <nlohmann/json.hpp>

#include "nn/precision.h"
#include "tests/support/file_bytes.h"
#include "tests/support/shared_data.h"

using lidarsim::testing::read_bytes;

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

// Runs lidar-infer with `args`; returns the exit code, stdout in `out`, stderr in `err`.
int run_infer_capturing(const std::string& args, std::string& out, std::string& err) {
  const fs::path exe = lidarsim::testing::binary_dir() / "infer" / "lidar-infer";
  // Per process: ctest runs this file's tests side by side.
  const std::string pid = std::to_string(::getpid());
  const fs::path out_file = fs::temp_directory_path() / ("lidarsim_precision_out_" + pid + ".txt");
  const fs::path err_file = fs::temp_directory_path() / ("lidarsim_precision_err_" + pid + ".txt");
  const int rc = std::system((exe.string() + " " + args + " >" + out_file.string() + " 2>" + err_file.string()).c_str());
  out = read_bytes(out_file);
  err = read_bytes(err_file);
  fs::remove(out_file);
  fs::remove(err_file);
  return WEXITSTATUS(rc);
}

}  // namespace

TEST(PredictCli, Bf16PrecisionStaysWithinTheMaeGateOfFp32) {
  const fs::path model = lidarsim::testing::source_dir() / "data/models/intensity_unet.h5";
  const fs::path scans = lidarsim::testing::source_dir() / "data/samples/semantickitti";
  double mae[2];
  for (int p = 0; p < 2; ++p) {
    const std::string precision = p ? "bf16" : "fp32";
    const fs::path dir = fs::temp_directory_path() / ("lidarsim_predict_" + precision);
    fs::remove_all(dir);
    std::string out, err;
    ASSERT_EQ(run_infer_capturing("predict --quiet --precision " + precision + " --model " + model.string() + " --semantickitti " +
                            scans.string() + " --out " + dir.string(),
                        out, err),
              0)
        << err;
    // The line names the precision that ran: bf16 only where the CPU has it.
    const bool ran_bf16 = p && nn::bf16_supported();
    EXPECT_NE(out.find(ran_bf16 ? "(bf16)" : "(fp32)"), std::string::npos) << out;
    if (p && !ran_bf16) {
      EXPECT_NE(err.find("running fp32"), std::string::npos) << err;
    }
    mae[p] = nlohmann::json::parse(read_bytes(dir / "summary.json")).at("mae").get<double>();
  }
  std::printf("[ measured ] bundled scan, all cells: MAE fp32 %.6f, bf16 %.6f\n", mae[0], mae[1]);
  EXPECT_LT(std::abs(mae[1] - mae[0]), 5e-4);
}

TEST(PredictCli, UnknownPrecisionIsOneLineNamingTheOption) {
  std::string out, err;
  const int rc = run_infer_capturing("predict --quiet --precision fp16 --model /nonexistent/model.h5 --scan /nonexistent.bin", out,
                           err);
  EXPECT_NE(rc, 0);
  EXPECT_NE(err.find("--precision"), std::string::npos) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
}
