// nuScenes-lidarseg labels (data/nuscenes_lidarseg.h): counts match the points, the ego car's
// points are dropped, the class table maps the 32-class taxonomy, bad files give clear errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>

#include "../support/shared_data.h"
#include "common/error.h"
#include "data/nuscenes_lidarseg.h"
#include "pgm/materials.h"
#include "temp_dir.h"

namespace lidarsim::data {
namespace {
namespace fs = std::filesystem;

ClassTable bundled_table() {
  return read_class_table(lidarsim::testing::source_dir() / "data/ontologies/nuscenes-lidarseg.csv");
}

// A scan of `labels.size()` points in nuScenes' own layout (x right, y forward), ring = i % 32.
void write_nuscenes_scan(const fs::path& dir, const std::string& id, const std::vector<std::uint8_t>& labels) {
  fs::create_directories(dir / "velodyne");
  fs::create_directories(dir / "labels");
  std::ofstream pcd(dir / "velodyne" / (id + ".pcd.bin"), std::ios::binary);
  for (std::size_t i = 0; i < labels.size(); ++i) {
    const float v[5] = {1.f + i, 10.f, -1.f, 40.f, static_cast<float>(i % 32)};
    pcd.write(reinterpret_cast<const char*>(v), sizeof v);
  }
  std::ofstream lab(dir / "labels" / (id + ".lidarseg.bin"), std::ios::binary);
  lab.write(reinterpret_cast<const char*>(labels.data()), static_cast<std::streamsize>(labels.size()));
}

TEST(NuscenesLidarseg, TableMapsEveryClassButTheEgo) {
  const ClassTable t = bundled_table();
  EXPECT_EQ(t.entries.size(), 32u);
  EXPECT_EQ(t.map(24), pgm::cls::road);
  EXPECT_EQ(t.map(17), pgm::cls::car);
  EXPECT_EQ(t.map(30), pgm::cls::vegetation);
  EXPECT_EQ(t.map(26), pgm::cls::sidewalk);
  EXPECT_EQ(t.map(kNuscenesEgoClass), -1);
}

TEST(NuscenesLidarseg, CountsMatchAndEgoIsDropped) {
  lidarsim::testing::TempDir tmp;
  write_nuscenes_scan(tmp.path(), "000000", {24, 31, 17, 31, 29, 30});
  const auto files = list_nuscenes_lidarseg(tmp.path());
  ASSERT_EQ(files.size(), 1u);
  const auto scan = read_nuscenes_lidarseg_scan(files[0], bundled_table());
  EXPECT_EQ(scan.read, 6u);
  EXPECT_EQ(scan.ego, 2u);
  ASSERT_EQ(scan.points.size(), 4u);
  EXPECT_EQ(scan.points[0].class_id, pgm::cls::road);
  EXPECT_EQ(scan.points[1].class_id, pgm::cls::car);
  EXPECT_EQ(scan.points[1].x, 10.f);  // the third point of the file: nuScenes y -> our x
  EXPECT_EQ(scan.points[1].y, -3.f);  // nuScenes x -> our -y
  EXPECT_EQ(scan.points[2].class_id, pgm::cls::unlabeled);  // static.other: unmapped
  EXPECT_EQ(scan.unmapped.at("static.other"), 1u);
  EXPECT_EQ(scan.points[3].material_id, pgm::default_material(pgm::cls::vegetation));
}

TEST(NuscenesLidarseg, TruncatedLabelFileIsAnErrorNamingIt) {
  lidarsim::testing::TempDir tmp;
  write_nuscenes_scan(tmp.path(), "000004", {24, 24, 24, 24});
  fs::resize_file(tmp / "labels/000004.lidarseg.bin", 3);
  const auto files = list_nuscenes_lidarseg(tmp.path());
  try {
    read_nuscenes_lidarseg_scan(files[0], bundled_table());
    FAIL() << "a truncated label file was accepted";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("000004.lidarseg.bin"), std::string::npos) << m;
    EXPECT_NE(m.find("truncated"), std::string::npos) << m;
  }
}

TEST(NuscenesLidarseg, BadLabelAndMissingFileAreErrors) {
  lidarsim::testing::TempDir tmp;
  write_nuscenes_scan(tmp.path(), "000000", {24, 32});
  try {
    read_nuscenes_lidarseg_labels(tmp / "labels/000000.lidarseg.bin", 2);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("point 1 label"), std::string::npos) << e.what();
  }
  fs::remove(tmp / "labels/000000.lidarseg.bin");
  try {
    list_nuscenes_lidarseg(tmp.path());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("000000.pcd.bin"), std::string::npos) << e.what();
  }
}

TEST(NuscenesLidarseg, ImportCountsTheDroppedEgoAndPointIndexIsTheFilesIndex) {
  lidarsim::testing::TempDir tmp;
  write_nuscenes_scan(tmp.path(), "000000", {31, 24, 31, 17, 29, 30});
  write_nuscenes_scan(tmp.path(), "000002", {24, 24, 31});
  ImportOptions o;
  o.layout = pgm::BeamLayout::from_file((lidarsim::testing::source_dir() / "data/sensors/hdl32e-nuscenes.json").string());
  o.class_table = lidarsim::testing::source_dir() / "data/ontologies/nuscenes-lidarseg.csv";
  o.extra_channels = {};
  ImportSummary s;
  const Dataset d = import_dataset(SourceFormat::NuscenesLidarseg, tmp.path(), o, &s);
  ASSERT_EQ(d.size(), 2);
  EXPECT_EQ(d.source_format, "nuscenes_lidarseg");
  EXPECT_EQ(s.points, 9);
  EXPECT_EQ(s.dropped_points, 3);
  EXPECT_EQ(s.classes, (std::map<std::string, long long>{{"road", 3}, {"car", 1}, {"unlabeled", 1}, {"vegetation", 1}}));
  EXPECT_EQ(s.unmapped, (std::map<std::string, long long>{{"static.other", 1}}));
  EXPECT_EQ(d.intensity_scale, intensity_scale::nuscenes_intensity());
  // Every kept point of frame 0 is in a cell of its own; the cell names its index in the file.
  const std::size_t plane = static_cast<std::size_t>(d.rows()) * d.cols();
  std::vector<int> indices;
  for (std::size_t k = 0; k < plane; ++k)
    if (d.point_index[k] >= 0) indices.push_back(d.point_index[k]);
  std::sort(indices.begin(), indices.end());
  EXPECT_EQ(indices, (std::vector<int>{1, 3, 4, 5}));
}

TEST(NuscenesLidarseg, SharedSceneImportsWithClasses) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "nuscenes-lidarseg-scene");
  const auto table = bundled_table();
  const auto files = list_nuscenes_lidarseg(dir);
  ASSERT_EQ(files.size(), 20u);
  const auto first = read_nuscenes_lidarseg_scan(files[0], table);
  EXPECT_EQ(first.read, 34720u);  // SOURCE.md
  EXPECT_EQ(first.points.size() + first.ego, first.read);
  EXPECT_GT(first.ego, 0u);
  const auto layout = pgm::BeamLayout::from_file((lidarsim::testing::source_dir() / "data/sensors/hdl32e-nuscenes.json").string());
  ImportOptions o;
  o.max_frames = 2;
  o.extra_channels = {"azimuth", "incidence"};
  const Dataset d = import_nuscenes_lidarseg(dir, layout, table, o);
  ASSERT_EQ(d.size(), 2);
  EXPECT_EQ(d.rows(), 32);
  EXPECT_EQ(d.frames[0], "nuscenes/nuscenes-lidarseg-scene/000000");
  // Road (flat.driveable_surface) is the largest class of the scene.
  const int ic = d.channel_index("class");
  const std::size_t plane = static_cast<std::size_t>(d.rows()) * d.cols();
  long road = 0, returns = 0;
  for (std::size_t k = 0; k < plane; ++k)
    if (d.mask.data()[k] > 0) ++returns, road += static_cast<int>(d.pgm.data()[ic * plane + k]) == pgm::cls::road;
  EXPECT_GT(returns, 20000);
  EXPECT_GT(road, returns / 5);
}

}  // namespace
}  // namespace lidarsim::data
