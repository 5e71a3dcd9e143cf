// Readers given impossible input: junk after numbers, singular matrices, absurd sizes and
// positions, out-of-range scans, frames past the end. Each is one Error naming file and field.
#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common/error.h"
#include "data/dataset.h"
#include "data/import.h"
#include "data/kitti_object.h"
#include "data/kitti_tracking.h"
#include "data/nuscenes.h"
#include "data/ouster.h"
#include "data/ply_reader.h"
#include "data/velodyne.h"
#include "tests/data/temp_dir.h"
#include "tests/support/file_limit.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using lidarsim::testing::error_of;
using lidarsim::testing::TempDir;

namespace {

const char* kCalibOk = "P2: 1 0 0 0 0 1 0 0 0 0 1 0\nR0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n";
const char* kLabelOk = "Car 0.00 0 0.0 100 100 200 200 1.5 1.6 3.9 2.0 1.6 10.0 0.1\n";

fs::path write_text(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << text;
  return p;
}

std::string calib_error(const TempDir& dir, const std::string& text) {
  const fs::path p = write_text(dir / "calib.txt", text);
  return error_of([&] { data::read_kitti_calib(p); });
}

std::string label_error(const TempDir& dir, const std::string& text) {
  const fs::path p = write_text(dir / "label.txt", text);
  return error_of([&] { data::read_kitti_object_labels(p); });
}

std::string scan_error(const TempDir& dir, const std::vector<float>& values) {
  const fs::path p = dir / "scan.bin";
  lidarsim::testing::write_binary(p, values);
  return error_of([&] { data::read_velodyne_bin(p); });
}

data::KittiCalib readers_axis_calib() {
  data::KittiCalib c;
  c.R0_rect.setIdentity();
  c.Tr_velo_to_cam << 0, -1, 0, 0, 0, 0, -1, 0, 1, 0, 0, 0;
  return c;
}

}  // namespace

TEST(ReaderReliability, KittiCalibRejectsTrailingJunkAndSingularMatrices) {
  TempDir dir;
  EXPECT_EQ(calib_error(dir, kCalibOk), "");
  EXPECT_NE(calib_error(dir, "R0_rect: 1 0 0 0 1 0 0 0 6.93x-03\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n")
                .find("R0_rect"),
            std::string::npos);
  const std::string singular_r0 = calib_error(dir, "R0_rect: 1 0 0 1 0 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n");
  EXPECT_NE(singular_r0.find("R0_rect"), std::string::npos) << singular_r0;
  EXPECT_NE(singular_r0.find("singular"), std::string::npos) << singular_r0;
  const std::string singular_tr = calib_error(dir, "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 0 0 0 0 0 -1 0 1 0 0 0\n");
  EXPECT_NE(singular_tr.find("Tr_velo_to_cam"), std::string::npos) << singular_tr;
}

TEST(ReaderReliability, KittiObjectLabelsRejectTrailingJunkAbsurdSizesAndPositions) {
  TempDir dir;
  EXPECT_EQ(label_error(dir, kLabelOk), "");
  EXPECT_NE(label_error(dir, "Car 0.00 0 0.0 100 100 200 200 1.5x 1.6 3.9 2.0 1.6 10.0 0.1\n").find("field 9"),
            std::string::npos);
  EXPECT_NE(label_error(dir, "Car 0.00 0 0.0 100 100 200 200 1.5 1.6 1e9 2.0 1.6 10.0 0.1\n").find("dimensions"),
            std::string::npos);
  EXPECT_NE(label_error(dir, "Car 0.00 0 0.0 100 100 200 200 1.5 1.6 3.9 1e30 1.6 10.0 0.1\n").find("location"),
            std::string::npos);
}

TEST(ReaderReliability, VelodyneScanRejectsAbsurdCoordinatesReflectanceAndEmptyScans) {
  TempDir dir;
  EXPECT_EQ(scan_error(dir, {1.f, 2.f, 0.5f, 0.3f}), "");
  EXPECT_NE(scan_error(dir, {1e30f, 2.f, 0.5f, 0.3f}).find("point 0 x"), std::string::npos);
  EXPECT_NE(scan_error(dir, {1.f, 2.f, 0.5f, -5.f}).find("reflectance"), std::string::npos);
  EXPECT_NE(scan_error(dir, {1.f, 2.f, 0.5f, 1e6f}).find("reflectance"), std::string::npos);
  EXPECT_NE(scan_error(dir, {}).find("empty"), std::string::npos);
  EXPECT_NE(scan_error(dir, {0.f, 0.f, 0.f, 0.1f, 0.f, 0.f, 0.f, 0.f}).find("all points"), std::string::npos);
}

TEST(ReaderReliability, KittiTrackingRejectsNegativeTrackIdsHugeFramesAndAbsurdBoxes) {
  TempDir dir;
  const data::KittiBoxConverter conv(readers_axis_calib());
  auto labels = [&](const std::string& line) {
    const fs::path p = write_text(dir / "label_02.txt", line);
    return error_of([&] { data::read_kitti_tracking_labels(p, conv); });
  };
  const std::string ok = "0 3 Car 0 0 0.1 100 100 200 200 1.5 1.6 3.9 2.0 1.6 10.0 0.1\n";
  EXPECT_EQ(labels(ok), "");
  EXPECT_NE(labels("0 -4 Car 0 0 0.1 100 100 200 200 1.5 1.6 3.9 2.0 1.6 10.0 0.1\n").find("track_id"), std::string::npos);
  EXPECT_NE(labels("999999999 3 Car 0 0 0.1 100 100 200 200 1.5 1.6 3.9 2.0 1.6 10.0 0.1\n").find("frame"),
            std::string::npos);
  EXPECT_NE(labels("0 3 Car 0 0 0.1 100 100 200 200 1.5 1.6 1e9 2.0 1.6 10.0 0.1\n").find("size"), std::string::npos);
  EXPECT_NE(labels("0 3 Car 0 0 0.1 100 100 200 200 1.5 1.6 3.9 1e30 1.6 10.0 0.1\n").find("position"),
            std::string::npos);
}

TEST(ReaderReliability, KittiTrackingDetectionsPastTheLastLabelledFrameAreAnError) {
  TempDir dir;
  write_text(dir / "calib" / "0001.txt", kCalibOk);
  write_text(dir / "label_02" / "0001.txt",
             "0 3 Car 0 0 0.1 100 100 200 200 1.5 1.6 3.9 2.0 1.6 10.0 0.1\n"
             "4 3 Car 0 0 0.1 100 100 200 200 1.5 1.6 3.9 2.0 1.6 10.0 0.1\n");
  write_text(dir / "detection" / "det_Car_val" / "0001.txt", "50,2,100,100,200,200,0.9,1.5,1.6,3.9,2.0,1.6,10.0,0.1,0.1\n");
  const std::string err = error_of([&] { data::read_kitti_tracking_sequence(dir.path(), "0001", "det"); });
  EXPECT_NE(err.find("frame"), std::string::npos) << err;
  EXPECT_NE(err.find("det_Car_val"), std::string::npos) << err;
}

TEST(ReaderReliability, ListedScanThatCannotBeReadIsAnError) {
  TempDir dir;
  const fs::path seq = dir / "sequences" / "00";
  lidarsim::testing::write_binary(seq / "velodyne" / "000000.bin", std::vector<float>{5.f, 1.f, 0.f, 0.5f});
  lidarsim::testing::write_binary(seq / "labels" / "000000.label", std::vector<std::uint32_t>{40});
  fs::create_symlink(dir / "nowhere.bin", seq / "velodyne" / "000001.bin");  // dangling
  lidarsim::testing::write_binary(seq / "labels" / "000001.label", std::vector<std::uint32_t>{40});
  const std::string err = error_of([&] { data::import_semantickitti(dir.path()); });
  EXPECT_NE(err.find("000001.bin"), std::string::npos) << "got: '" << err << "'";
}

TEST(DatasetReliability, WriteOnAFullDiskThrowsExitsCleanlyAndKeepsThePreviousFile) {
  TempDir dir;
  data::Dataset d;
  d.channels = {"range"};
  const auto layout = pgm::BeamLayout::uniform(16, 2.0, -24.0, 256);
  for (int f = 0; f < 3; ++f) {
    pgm::PolarGridMap map(layout, {"range", "intensity", "mask"});
    for (int r = 0; r < map.rows(); ++r)
      for (int c = 0; c < map.cols(); ++c) {
        map.at(0, r, c) = static_cast<float>((r * 31 + c * 17 + f * 7) % 101);
        map.at(1, r, c) = static_cast<float>((r * 13 + c * 5 + f) % 97) / 97.f;
        map.at(2, r, c) = 1.f;
      }
    d.append(map, "f" + std::to_string(f), "ring");
  }
  const fs::path path = dir / "d.h5";
  data::write_dataset(path, d);
  std::ifstream in0(path, std::ios::binary);
  const std::string before{std::istreambuf_iterator<char>(in0), std::istreambuf_iterator<char>()};
  d.frames[0] = "changed";
  ASSERT_GT(before.size(), 512u);
  const std::string status = lidarsim::testing::run_with_file_size_limit(512, [&] {
    try {
      data::write_dataset(path, d);
    } catch (const Error&) {
      return 3;
    }
    return 0;
  });
  EXPECT_EQ(status, "exit 3");
  std::ifstream in1(path, std::ios::binary);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in1), std::istreambuf_iterator<char>()), before);
}

TEST(DatasetReliability, NoBitFlipInTheNumericDataLoadsChangedValues) {
  TempDir dir;
  data::Dataset d;
  d.channels = {"range"};
  const auto layout = pgm::BeamLayout::uniform(4, 2.0, -24.0, 32);
  pgm::PolarGridMap map(layout, {"range", "intensity", "mask"});
  for (int r = 0; r < map.rows(); ++r)
    for (int c = 0; c < map.cols(); ++c) {
      map.at(0, r, c) = 1.f + r + 0.37f * c;
      map.at(1, r, c) = 0.01f * ((r * 7 + c) % 90);
      map.at(2, r, c) = (r + c) % 3 ? 1.f : 0.f;
    }
  d.append(map, "f0", "ring");
  const fs::path path = dir / "d.h5", copy = dir / "flipped.h5";
  data::write_dataset(path, d);
  std::ifstream in(path, std::ios::binary);
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  int accepted = 0, changed = 0;
  // About 1,500 offsets spread over the whole file (headers, checksums and data alike).
  const std::size_t stride = std::max<std::size_t>(1, bytes.size() / 1500);
  for (std::size_t at = 0; at < bytes.size(); at += stride) {
    std::string flipped = bytes;
    flipped[at] = static_cast<char>(flipped[at] ^ (1 << (at % 8)));
    std::ofstream(copy, std::ios::binary | std::ios::trunc).write(flipped.data(), static_cast<std::streamsize>(flipped.size()));
    data::Dataset got;
    try {
      got = data::read_dataset(copy);
    } catch (const Error&) {
      continue;
    }
    ++accepted;
    const bool same = std::equal(got.pgm.begin(), got.pgm.end(), d.pgm.begin(), d.pgm.end()) &&
                      std::equal(got.target.begin(), got.target.end(), d.target.begin(), d.target.end()) &&
                      std::equal(got.mask.begin(), got.mask.end(), d.mask.begin(), d.mask.end()) &&
                      got.point_index == d.point_index;
    if (!same) ++changed;
  }
  std::printf("%zu bytes, every %zu-th flipped: %d accepted, %d with changed values\n", bytes.size(), stride, accepted, changed);
  EXPECT_EQ(changed, 0);
}

// Found by fuzzing (fuzz/regressions/ply/): the header's vertex count was trusted before the
// data was measured, so "element vertex 100000000000000" allocated columns for 1e14 vertices
// (std::bad_alloc, no file, no field) and a count whose size overflowed passed the check.
TEST(ReaderReliability, PlyVertexCountBeyondTheFileIsAnErrorBeforeAnyAllocation) {
  const TempDir dir;
  const std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex %s\nproperty float x\nend_header\n";
  for (const std::string count : {"100000000000000", "4611686018427387905", "18446744073709551615"}) {
    std::string text = header;
    text.replace(text.find("%s"), 2, count);
    const fs::path p = write_text(dir / "cloud.ply", text + "abcdefgh");
    const std::string e = error_of([&] { data::read_ply(p); });
    EXPECT_NE(e.find("cloud.ply"), std::string::npos) << count << ": " << e;
    EXPECT_NE(e.find("vertex"), std::string::npos) << count << ": " << e;
  }
  const fs::path ascii = write_text(dir / "ascii.ply", "ply\nformat ascii 1.0\nelement vertex 100000000000000\nproperty float x\nend_header\n1\n");
  EXPECT_NE(error_of([&] { data::read_ply(ascii); }).find("ascii.ply"), std::string::npos);
}

// Found by fuzzing (fuzz/regressions/nuscenes/, UBSan): a ring of 1.4e33 was cast to int before
// its range was checked (undefined behaviour); now the range check comes first.
TEST(ReaderReliability, NuscenesRingFarBeyondIntIsAnErrorNamingTheField) {
  const TempDir dir;
  const fs::path p = dir / "sweep.pcd.bin";
  lidarsim::testing::write_binary(p, std::vector<float>{1.f, 2.f, 0.5f, 10.f, 1.43e33f});
  const std::string e = error_of([&] { data::read_nuscenes_pcd_bin(p); });
  EXPECT_NE(e.find("point 0 ring"), std::string::npos) << e;
}

// Found by fuzzing (fuzz/regressions/ouster_metadata/): a metadata file that is a bare number,
// or whose prod_line is not a string, threw nlohmann's type_error (no file, no field).
TEST(ReaderReliability, OusterMetadataOfTheWrongJsonTypesNamesTheFileAndField) {
  const TempDir dir;
  EXPECT_NE(error_of([&] { data::read_ouster_metadata(write_text(dir / "meta.json", "8")); }).find("meta.json: file"),
            std::string::npos);
  const std::string e = error_of([&] {
    data::read_ouster_metadata(write_text(dir / "meta2.json", R"({"prod_line": 5, "data_format": {}})"));
  });
  EXPECT_NE(e.find("meta2.json"), std::string::npos) << e;
  EXPECT_NE(e.find("prod_line"), std::string::npos) << e;
}
