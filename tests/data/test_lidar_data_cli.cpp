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
  EXPECT_NE(r.output.find("--nuscenes-lidarseg"), std::string::npos);
  EXPECT_NE(r.output.find("--semantickitti-mos"), std::string::npos);
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

// nuScenes-lidarseg sweeps (x right, y forward, ring = i % 32) with one label per point.
void write_lidarseg_scan(const std::filesystem::path& dir, const std::vector<std::uint8_t>& labels) {
  std::vector<float> pts;
  for (std::size_t i = 0; i < labels.size(); ++i) pts.insert(pts.end(), {1.f + i, 10.f, -1.f, 40.f, float(i % 32)});
  write_binary(dir / "velodyne/000000.pcd.bin", pts);
  write_binary(dir / "labels/000000.lidarseg.bin", labels);
}

TEST(LidarDataCli, ImportsNuscenesLidarsegWithTheBundledSensorAndClassTable) {
  REQUIRE_EXE();
  TempDir dir;
  write_lidarseg_scan(dir / "scene", {24, 31, 24, 17, 31, 29});
  const auto r = run("import --quiet --nuscenes-lidarseg " + (dir / "scene").string() + " --out " + (dir / "n.h5").string());
  ASSERT_EQ(r.code, 0) << r.output;
  for (const char* line : {"points: 6 read, 2 dropped by the reader (nuScenes-lidarseg: vehicle.ego), 4 imported",
                           "classes (points): road 2, car 1, unlabeled 1", "imported as unlabeled (no class of ours): static.other 1",
                           "intensity scale: nuscenes_intensity_0_255 (value / 255)"})
    EXPECT_NE(r.output.find(line), std::string::npos) << line << " missing in:\n" << r.output;
  const auto info = run("info " + (dir / "n.h5").string());
  EXPECT_NE(info.output.find("format: nuscenes_lidarseg"), std::string::npos) << info.output;
  EXPECT_NE(info.output.find("grid: 32 x 1024"), std::string::npos) << info.output;
  EXPECT_NE(info.output.find("intensity scale: nuscenes_intensity_0_255"), std::string::npos) << info.output;
  // A label file one byte short names itself.
  std::filesystem::resize_file(dir / "scene/labels/000000.lidarseg.bin", 5);
  expect_one_error_line(run("import --quiet --nuscenes-lidarseg " + (dir / "scene").string() + " --out " + (dir / "m.h5").string()),
                        "000000.lidarseg.bin: size:");
}

TEST(LidarDataCli, MovingObjectLabelsOnlyWithTheirOwnOption) {
  REQUIRE_EXE();
  TempDir dir;
  write_scan(dir / "seq");  // semantic labels (50, 40) in labels/
  expect_one_error_line(run("import --quiet --semantickitti-mos " + (dir / "seq").string() + " --out " + (dir / "m.h5").string()),
                        "000000.label: point 0 label: lower 16 bits are 50, not a moving-object label");
  std::vector<std::uint32_t> mos(6400, 8u);
  mos[100] = 251u;
  write_binary(dir / "seq/labels_mos/000000.label", mos);
  const auto r = run("import --quiet --semantickitti-mos " + (dir / "seq").string() + " --out " + (dir / "m.h5").string());
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("motion (points): static 6399, moving 1"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("classes (points): unlabeled 6400"), std::string::npos) << r.output;
  const auto d = data::read_dataset(dir / "m.h5", {"motion"});
  EXPECT_EQ(d.source_format, "semantickitti_mos");
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
      {"--kitti-object", "kitti-object-more/training", "64 x 1024", "kitti_object/-: 9"},
      {"--nuscenes-lidarseg", "nuscenes-lidarseg-scene", "32 x 1024", "nuscenes/nuscenes-lidarseg-scene: 20"},
      {"--semantickitti-mos", "semantickitti-seq08-mos-sample", "64 x 1024",
       "semantickitti/semantickitti-seq08-mos-sample: 3"}};
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
    if (c.flag != "--kitti-object" && c.flag != "--semantickitti-mos") {
      EXPECT_NE(info.output.find("row modes: ring: "), std::string::npos) << info.output;
    }
  }
}
