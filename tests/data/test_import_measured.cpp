// lidar-data import on the measured scans of ../shared/data that the new readers open: the
// nuScenes-lidarseg scene and the SemanticKITTI sequence 08 scans with moving-object labels.
// Every count is the one their SOURCE.md verified with other tools.
#include <gtest/gtest.h>

#include <filesystem>

#include "data/dataset_reader.h"
#include "data/import.h"
#include "tests/data/temp_dir.h"
#include "tests/support/shared_data.h"

namespace lidarsim::data {
namespace {
namespace fs = std::filesystem;
using lidarsim::testing::source_dir;
using lidarsim::testing::TempDir;

TEST(ImportMeasuredStatistical, NuscenesLidarsegSceneMatchesItsSourceCounts) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "nuscenes-lidarseg-scene");
  TempDir tmp;
  ImportOptions o;
  o.layout = pgm::BeamLayout::from_file((source_dir() / "data/sensors/hdl32e-nuscenes.json").string());
  o.class_table = source_dir() / "data/ontologies/nuscenes-lidarseg.csv";
  const ImportSummary s = import_to_file(SourceFormat::NuscenesLidarseg, dir, tmp / "nl.h5", o);
  EXPECT_EQ(s.frames, 20);
  EXPECT_EQ(s.points, 694368);          // SOURCE.md: points per frame, summed
  EXPECT_EQ(s.dropped_points, 168115);  // SOURCE.md: 31 vehicle.ego
  EXPECT_TRUE(s.unmapped.empty());      // no animal or static.other in the scene
  // SOURCE.md's histogram through data/ontologies/nuscenes-lidarseg.csv.
  const std::map<std::string, long long> want = {
      {"road", 193871},          {"terrain", 102567},   {"other_structure", 70356}, {"truck", 56392},
      {"vegetation", 52813},     {"sidewalk", 46766},   {"person", 120 + 1057},     {"other_object", 971 + 56},
      {"car", 793},              {"other_vehicle", 384}, {"unlabeled", 102},         {"other_ground", 5}};
  EXPECT_EQ(s.classes, want);
  EXPECT_EQ(s.intensity_scale, intensity_scale::nuscenes_intensity());
  const DatasetReader in(tmp / "nl.h5");
  EXPECT_EQ(in.header().source_format, "nuscenes_lidarseg");
  EXPECT_EQ(in.header().intensity_scale, intensity_scale::nuscenes_intensity());
  EXPECT_EQ(in.rows(), 32);
  EXPECT_EQ(in.header().frame_place(0), (FramePlace{"nuscenes", "nuscenes-lidarseg-scene", "000000"}));
  EXPECT_EQ(s.row_modes.at("ring"), 20);
}

TEST(ImportMeasuredStatistical, Seq08MosScansImportWithClassUnlabeledAndTheirMotion) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq08-mos-sample");
  TempDir tmp;
  const ImportSummary s = import_to_file(SourceFormat::SemanticKittiMos, dir, tmp / "mos.h5");
  EXPECT_EQ(s.frames, 3);
  EXPECT_EQ(s.points, 122426 + 115759 + 119458);  // SOURCE.md
  EXPECT_EQ(s.dropped_points, 0);
  EXPECT_EQ(s.motion.at("static"), 110268 + 96688 + 101254);
  EXPECT_EQ(s.motion.at("movable"), 12158 + 19049 + 18185);
  EXPECT_EQ(s.motion.at("moving"), 22 + 19);
  EXPECT_EQ(s.classes, (std::map<std::string, long long>{{"unlabeled", s.points}}));
  EXPECT_EQ(s.intensity_scale, intensity_scale::kitti_reflectance());
  EXPECT_EQ(s.row_modes.at("firing_order"), 3);  // KITTI .bin files in firing order: 64 rows each
  const DatasetReader in(tmp / "mos.h5");
  EXPECT_EQ(in.header().channels.back(), "motion");
  EXPECT_EQ(in.header().frame_place(0).source, "semantickitti");
}

TEST(ImportMeasuredStatistical, RellisScansOnTwoIntensityScalesAreRefusedInOneDataset) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "rellis3d-os1-sample");
  TempDir tmp;
  // The sample scan with its PLY (reflectivity), and a copy without one (the .bin's intensity).
  for (const auto& e : fs::directory_iterator(dir)) fs::copy(e.path(), tmp / e.path().filename().string());
  fs::copy(dir / "000104.bin", tmp / "000105.bin");
  fs::copy(dir / "000104.label", tmp / "000105.label");
  ImportOptions o;
  o.layout = pgm::BeamLayout::from_file((source_dir() / "data/sensors/os1-64-rellis3d.json").string());
  o.class_table = source_dir() / "data/ontologies/rellis3d.csv";
  const std::string err = lidarsim::testing::error_of([&] { import_dataset(SourceFormat::Rellis3d, tmp.path(), o); });
  EXPECT_NE(err.find("000105.bin: intensity: on the scale rellis3d_bin_intensity"), std::string::npos) << err;
  EXPECT_NE(err.find("rellis3d_reflectivity_16bit"), std::string::npos) << err;
  o.max_frames = 1;  // the scan with its PLY alone
  EXPECT_EQ(import_dataset(SourceFormat::Rellis3d, tmp.path(), o).intensity_scale, intensity_scale::rellis3d_reflectivity());
}

}  // namespace
}  // namespace lidarsim::data
