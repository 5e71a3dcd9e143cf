#include <gtest/gtest.h>

#include <cmath>

#include "common/error.h"
#include "data/velodyne.h"
#include "tests/data/temp_dir.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;
using lidarsim::testing::error_of;
using lidarsim::testing::write_binary;

TEST(Velodyne, ReadsFloat32RecordsAsPoints) {
  TempDir dir;
  write_binary(dir / "a.bin", std::vector<float>{1, 2, 3, 0.5f, -4, 5, -6, 0.25f});
  const auto pts = data::read_velodyne_bin(dir / "a.bin");
  ASSERT_EQ(pts.size(), 2u);
  EXPECT_EQ(pts[1].x, -4.f);
  EXPECT_EQ(pts[1].z, -6.f);
  EXPECT_EQ(pts[1].intensity, 0.25f);
}

TEST(Velodyne, TruncatedBinNamesFileAndSize) {
  TempDir dir;
  write_binary(dir / "cut.bin", std::vector<float>{1, 2, 3, 0.5f, 1, 2}, 0);  // 24 bytes
  const std::string msg = error_of([&] { data::read_velodyne_bin(dir / "cut.bin"); });
  EXPECT_NE(msg.find("cut.bin: size:"), std::string::npos) << msg;
  EXPECT_NE(msg.find("multiple of 16"), std::string::npos) << msg;
}

TEST(Velodyne, NanCoordinateNamesFileAndPoint) {
  TempDir dir;
  write_binary(dir / "nan.bin", std::vector<float>{1, 2, 3, 0.5f, 1, NAN, 3, 0.5f});
  const std::string msg = error_of([&] { data::read_velodyne_bin(dir / "nan.bin"); });
  EXPECT_NE(msg.find("nan.bin: point 1 y"), std::string::npos) << msg;
}

TEST(Velodyne, InfiniteReflectanceIsAnError) {
  TempDir dir;
  write_binary(dir / "inf.bin", std::vector<float>{1, 2, 3, INFINITY});
  EXPECT_NE(error_of([&] { data::read_velodyne_bin(dir / "inf.bin"); }).find("reflectance"), std::string::npos);
}

TEST(Velodyne, LabelCountDifferentFromPointsNamesBothCounts) {
  TempDir dir;
  write_binary(dir / "a.label", std::vector<std::uint32_t>{10, 40, 40});
  const std::string msg = error_of([&] { data::read_label_file(dir / "a.label", 2); });
  EXPECT_NE(msg.find("a.label: label count"), std::string::npos) << msg;
  EXPECT_NE(msg.find("3 labels"), std::string::npos) << msg;
  EXPECT_NE(msg.find("2 points"), std::string::npos) << msg;
  EXPECT_EQ(data::read_label_file(dir / "a.label", 3).size(), 3u);
}

TEST(Velodyne, MissingFileIsAnError) {
  EXPECT_NE(error_of([] { data::read_velodyne_bin("/nonexistent/x.bin"); }).find("x.bin"), std::string::npos);
}
