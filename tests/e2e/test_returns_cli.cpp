// lidar-qualify returns end to end: bad places give one clear error line; on the measured data the
// command reproduces the shipped model's counts exactly and writes the held-out table.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

#include "sensor/return_model.h"
#include "tests/support/shared_data.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

struct ReturnsCliRun {
  int code = -1;
  std::string out;  // stdout + stderr
};

ReturnsCliRun run_returns(const std::string& args) {
  const std::string cmd =
      (lidarsim::testing::binary_dir() / "qualify" / "lidar-qualify").string() + " returns " + args + " 2>&1";
  ReturnsCliRun r;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf{};
  while (fgets(buf.data(), buf.size(), p)) r.out += buf.data();
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

}  // namespace

TEST(ReturnsCli, BadPlacesAreOneClearErrorLine) {
  const auto no_format = run_returns("--place seq00 --place b=semantickitti:x --out /tmp/unused");
  EXPECT_NE(no_format.code, 0);
  EXPECT_NE(no_format.out.find("error: --place: expected NAME=FORMAT:DIR"), std::string::npos) << no_format.out;
  const auto unknown = run_returns("--place a=lidarish:/x --place b=lidarish:/y --out /tmp/unused");
  EXPECT_NE(unknown.code, 0);
  EXPECT_NE(unknown.out.find("unknown format \"lidarish\""), std::string::npos) << unknown.out;
  const auto one = run_returns("--place a=semantickitti:/x --out /tmp/unused");
  EXPECT_NE(one.out.find("at least two"), std::string::npos) << one.out;
}

TEST(ReturnsCliStatistical, ReproducesTheShippedModelAndWritesTheHeldOutTable) {
  LIDARSIM_REQUIRE_SHARED_DATA(root, "");
  for (const char* sub : {"semantickitti-seq00-sample", "semantickitti-seq08-mos-sample", "kitti-object-sample",
                          "kitti-object-more", "nuscenes-lidarseg-scene", "rellis3d-os1-sample"})
    if (!fs::exists(root / sub)) GTEST_SKIP() << "measured data not found: " << (root / sub);
  const fs::path out = fs::temp_directory_path() / ("lidarsim_returns_cli_" + std::to_string(::getpid()));
  const std::string r = root.string() + "/";
  const auto res = run_returns("--place seq00=semantickitti:" + r + "semantickitti-seq00-sample --place seq08=semantickitti:" +
                               r + "semantickitti-seq08-mos-sample --place kitti-object=kitti_object:" + r +
                               "kitti-object-sample --place kitti-object=kitti_object:" + r +
                               "kitti-object-more --place nuscenes=nuscenes_lidarseg:" + r +
                               "nuscenes-lidarseg-scene --place rellis3d=rellis3d:" + r + "rellis3d-os1-sample --out " +
                               out.string() + " --out-model " + (out / "m.json").string() + " --model-sensor hdl64e");
  ASSERT_EQ(res.code, 0) << res.out;
  EXPECT_TRUE(fs::exists(out / "report.md"));
  const auto fitted = sensor::ReturnModel::load((out / "m.json").string());
  const auto shipped = sensor::ReturnModel::load((lidarsim::testing::source_dir() / "data/models/returns_hdl64e.json").string());
  EXPECT_EQ(fitted.counts().cells, shipped.counts().cells) << "data/models/returns_hdl64e.json is not what the command fits";
  EXPECT_EQ(fitted.counts().returns, shipped.counts().returns);
  EXPECT_EQ(fitted.fit_places, shipped.fit_places);
  fs::remove_all(out);
}
