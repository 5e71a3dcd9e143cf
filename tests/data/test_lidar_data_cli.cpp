// End-to-end: the lidar-data command on good and bad input (one line "error: ...", non-zero exit).
#include <gtest/gtest.h>
#include <hdf5.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <sys/wait.h>

#include "data/dataset.h"
#include "tests/data/temp_dir.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;
using lidarsim::testing::write_binary;

namespace {

struct Run {
  int code = -1;
  std::string output;  // stdout + stderr
};

std::filesystem::path exe() { return lidarsim::testing::binary_dir() / "data" / "lidar-data"; }

Run run(const std::string& args) {
  Run r;
  const std::string cmd = exe().string() + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  while (std::fgets(buf.data(), buf.size(), p)) r.output += buf.data();
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

#define REQUIRE_EXE()                                                                         \
  do {                                                                                        \
    if (!std::filesystem::exists(exe())) {                                                    \
      if (lidarsim::testing::running_in_ci()) FAIL() << "lidar-data not built: " << exe();   \
      GTEST_SKIP() << "build the lidar-data target first: " << exe();                         \
    }                                                                                         \
  } while (0)

// A ring-ordered synthetic scan (64 rings on the HDL-64E elevations) with labels.
void write_scan(const std::filesystem::path& seq, std::size_t label_count_delta = 0, bool nan = false) {
  const auto layout = pgm::BeamLayout::hdl64e(1024);
  std::vector<float> pts;
  std::vector<std::uint32_t> labels;
  for (int r = 0; r < 64; ++r)
    for (int k = 0; k < 100; ++k) {
      const double az = (k + 0.5) * 2 * M_PI / 100, el = layout.elevations_rad[r];
      pts.insert(pts.end(), {float(10 * std::cos(el) * std::cos(az)), float(10 * std::cos(el) * std::sin(az)),
                             float(10 * std::sin(el)), 0.3f});
      labels.push_back(r < 32 ? 50 : 40);
    }
  if (nan) pts[4 * 17 + 2] = NAN;
  labels.resize(labels.size() + label_count_delta, 40);
  write_binary(seq / "velodyne" / "000000.bin", pts);
  write_binary(seq / "labels" / "000000.label", labels);
}

void expect_one_error_line(const Run& r, const std::string& must_contain) {
  EXPECT_NE(r.code, 0) << r.output;
  ASSERT_GE(r.output.size(), 7u) << r.output;
  EXPECT_EQ(r.output.rfind("error: ", 0), 0u) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_NE(r.output.find(must_contain), std::string::npos) << r.output;
}

}  // namespace

TEST(LidarDataCli, HelpListsTheImportOptions) {
  REQUIRE_EXE();
  const auto r = run("import --help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.output.find("--semantickitti"), std::string::npos);
  EXPECT_NE(r.output.find("--kitti-object"), std::string::npos);
  EXPECT_NE(r.output.find("--columns"), std::string::npos);
  EXPECT_EQ(run("--help").code, 0);
}

TEST(LidarDataCli, ImportsASyntheticSequenceIntoAReadableDataset) {
  REQUIRE_EXE();
  TempDir dir;
  write_scan(dir / "seq");
  const auto r = run("import --quiet --semantickitti " + (dir / "seq").string() + " --columns 2048 --out " +
                     (dir / "d.h5").string());
  ASSERT_EQ(r.code, 0) << r.output;
  const auto d = data::read_dataset(dir / "d.h5", {"range", "class", "material", "incidence"});
  EXPECT_EQ(d.size(), 1);
  EXPECT_EQ(d.cols(), 2048);
  EXPECT_EQ(d.row_modes.at(0), "firing_order");
  float returns = 0;
  for (float m : std::vector<float>(d.mask.begin(), d.mask.end())) returns += m;
  EXPECT_EQ(returns, 6400.f);  // every point has its own cell
}

TEST(LidarDataCli, TruncatedBinFailsNamingTheFile) {
  REQUIRE_EXE();
  TempDir dir;
  write_scan(dir / "seq");
  std::filesystem::resize_file(dir / "seq/velodyne/000000.bin", 16 * 100 + 10);
  expect_one_error_line(run("import --quiet --semantickitti " + (dir / "seq").string() + " --out " + (dir / "d.h5").string()),
                        "000000.bin: size:");
  EXPECT_FALSE(std::filesystem::exists(dir / "d.h5"));
}

TEST(LidarDataCli, LabelCountMismatchFailsNamingTheLabelFile) {
  REQUIRE_EXE();
  TempDir dir;
  write_scan(dir / "seq", 5);
  expect_one_error_line(run("import --quiet --semantickitti " + (dir / "seq").string() + " --out " + (dir / "d.h5").string()),
                        "000000.label: label count");
}

TEST(LidarDataCli, NanCoordinateFailsNamingFileAndPoint) {
  REQUIRE_EXE();
  TempDir dir;
  write_scan(dir / "seq", 0, true);
  expect_one_error_line(run("import --quiet --semantickitti " + (dir / "seq").string() + " --out " + (dir / "d.h5").string()),
                        "000000.bin: point 17 z");
}

TEST(LidarDataCli, DatasetWithMissingChannelOrDatasetFailsNamingIt) {
  REQUIRE_EXE();
  TempDir dir;
  write_scan(dir / "seq");
  ASSERT_EQ(run("import --quiet --semantickitti " + (dir / "seq").string() + " --channels height --out " +
                (dir / "d.h5").string()).code, 0);
  // The dataset lacks nothing the baselines need: works.
  EXPECT_EQ(run("baselines " + (dir / "d.h5").string()).code, 0);
  // Without the class channel (attribute rewritten), baselines must refuse naming it.
  {
    hid_t f = H5Fopen((dir / "d.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    ASSERT_GE(f, 0);
    H5Adelete(f, "channels");
    hid_t type = H5Tcopy(H5T_C_S1);
    H5Tset_size(type, H5T_VARIABLE);
    hid_t space = H5Screate(H5S_SCALAR);
    hid_t a = H5Acreate2(f, "channels", type, space, H5P_DEFAULT, H5P_DEFAULT);
    const char* text = R"(["range","label","material","height"])";
    H5Awrite(a, type, &text);
    H5Aclose(a), H5Sclose(space), H5Tclose(type);
    H5Fclose(f);
  }
  expect_one_error_line(run("baselines " + (dir / "d.h5").string()), "d.h5: /pgm channel 'class': missing");
  // Without /target.
  ASSERT_EQ(run("import --quiet --semantickitti " + (dir / "seq").string() + " --out " + (dir / "e.h5").string()).code, 0);
  {
    hid_t f = H5Fopen((dir / "e.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    ASSERT_GE(f, 0);
    H5Ldelete(f, "/target", H5P_DEFAULT);
    H5Fclose(f);
  }
  expect_one_error_line(run("info " + (dir / "e.h5").string()), "e.h5: dataset /target: missing");
}

TEST(LidarDataCli, UnknownOptionsAndMissingSourceAreOneLineErrors) {
  REQUIRE_EXE();
  TempDir dir;
  expect_one_error_line(run("import --out " + (dir / "x.h5").string()), "--semantickitti");
  expect_one_error_line(run("import --semantickitti /nonexistent/sk --out " + (dir / "x.h5").string()), "/nonexistent/sk");
}

TEST(LidarDataCliReal, EverySensorFormatImportsAtItsOwnResolutionAndInfoNamesItsPlaces) {
  REQUIRE_EXE();
  LIDARSIM_REQUIRE_SHARED_DATA(shared, "");
  TempDir dir;
  struct Case {
    std::string flag, source, rows_cols, place;
  };
  const Case cases[] = {
      {"--nuscenes", "nuscenes-sample-frame", "32 x 1024", "nuscenes/n015-2018-07-24-11-22-45+0800: 1"},
      {"--rellis3d", "rellis3d-os1-sample", "64 x 2048", "rellis3d/rellis3d-os1-sample: 1"},
      {"--ouster", "ouster-sample-pcaps/OS-1-128_v2.3.0_1024x10_lb_n3.pcap", "128 x 1024",
       "ouster/OS-1-128_v2.3.0_1024x10_lb_n3: 3"},
      {"--kitti-object", "kitti-object-more/training", "64 x 1024", "kitti_object/-: 9"}};
  for (const auto& c : cases) {
    SCOPED_TRACE(c.flag);
    const auto out = dir / (c.flag.substr(2) + ".h5");
    const ::Run imp = run("import " + c.flag + " " + (shared / c.source).string() + " --out " + out.string() + " --quiet");
    ASSERT_EQ(imp.code, 0) << imp.output;
    const ::Run info = run("info " + out.string());
    ASSERT_EQ(info.code, 0) << info.output;
    EXPECT_NE(info.output.find("grid: " + c.rows_cols), std::string::npos) << info.output;
    EXPECT_NE(info.output.find(c.place), std::string::npos) << info.output;
    // Sensors that record a ring index get their rows from it.
    if (c.flag != "--kitti-object") {
      EXPECT_NE(info.output.find("row modes: ring: "), std::string::npos) << info.output;
    }
  }
}
