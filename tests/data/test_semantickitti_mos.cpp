// SemanticKITTI scans with moving-object labels only (data/semantickitti_mos.h): class unlabeled,
// the motion in its own channel, and clear errors for label files that do not fit their scan.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "common/error.h"
#include "data/import.h"
#include "data/semantickitti_mos.h"
#include "pgm/materials.h"
#include "tests/data/temp_dir.h"

namespace lidarsim::data {
namespace {
namespace fs = std::filesystem;
using lidarsim::testing::error_of;
using lidarsim::testing::TempDir;
using lidarsim::testing::write_binary;

constexpr int kRings = 64, kPerRing = 50;

// Label of point i: rings 0-9 moving, 10-29 movable (with an instance id in the upper bits), the
// rest static.
std::uint32_t mos_label(int i) {
  const int ring = i / kPerRing;
  if (ring < 10) return kMosMoving;
  if (ring < 30) return (7u << 16) | kMosMovable;
  return kMosStatic;
}

Motion expected_motion(int i) {
  const std::uint32_t v = mos_label(i) & 0xFFFFu;
  return v == kMosMoving ? Motion::Moving : v == kMosMovable ? Motion::Movable : Motion::Static;
}

// A scan in firing order on the HDL-64E elevations (ring by ring), 10 m away, and its MOS labels
// in `label_folder`; `label_delta` labels more (or fewer) than points.
void write_mos_scan(const fs::path& seq, const std::string& id, int label_delta = 0,
                    const std::string& label_folder = "labels_mos") {
  const auto layout = pgm::BeamLayout::hdl64e(1024);
  std::vector<float> pts;
  std::vector<std::uint32_t> labels;
  for (int r = 0; r < kRings; ++r)
    for (int k = 0; k < kPerRing; ++k) {
      const double az = (k + 0.5) * 2 * M_PI / kPerRing, el = layout.elevations_rad[r];
      pts.insert(pts.end(), {float(10 * std::cos(el) * std::cos(az)), float(10 * std::cos(el) * std::sin(az)),
                             float(10 * std::sin(el)), 0.25f});
      labels.push_back(mos_label(r * kPerRing + k));
    }
  if (label_delta < 0) labels.resize(labels.size() + label_delta);
  for (int i = 0; i < label_delta; ++i) labels.push_back(kMosStatic);
  write_binary(seq / "velodyne" / (id + ".bin"), pts);
  write_binary(seq / label_folder / (id + ".label"), labels);
}

TEST(SemanticKittiMos, ImportsClassUnlabeledWithTheMotionOfEachCellsPoint) {
  TempDir tmp;
  write_mos_scan(tmp / "08", "000540");
  ImportOptions o;
  o.extra_channels = {};
  ImportSummary summary;
  const Dataset d = import_dataset(SourceFormat::SemanticKittiMos, tmp / "08", o, &summary);
  ASSERT_EQ(d.size(), 1);
  EXPECT_EQ(d.source_format, "semantickitti_mos");
  EXPECT_EQ(d.frames[0], "semantickitti/08/000540");
  EXPECT_EQ(d.frame_place(0), (FramePlace{"semantickitti", "08", "000540"}));
  EXPECT_EQ(d.intensity_scale, intensity_scale::kitti_reflectance());
  ASSERT_EQ(d.channels, (std::vector<std::string>{"range", "class", "material", "motion"}));
  const std::size_t plane = static_cast<std::size_t>(d.rows()) * d.cols();
  const float* cls = d.pgm.data() + d.channel_index("class") * plane;
  const float* material = d.pgm.data() + d.channel_index("material") * plane;
  const float* motion = d.pgm.data() + d.channel_index("motion") * plane;
  int returns = 0, moving = 0;
  for (std::size_t k = 0; k < plane; ++k) {
    if (d.mask.data()[k] == 0) {
      EXPECT_EQ(motion[k], 0.f);
      continue;
    }
    ++returns;
    const int point = d.point_index[k];
    ASSERT_GE(point, 0);
    EXPECT_EQ(cls[k], pgm::cls::unlabeled);
    EXPECT_EQ(material[k], pgm::material::unknown);
    EXPECT_EQ(motion[k], static_cast<float>(expected_motion(point))) << "cell " << k << ", point " << point;
    moving += motion[k] == static_cast<float>(Motion::Moving);
  }
  EXPECT_EQ(returns, kRings * kPerRing);  // one point per cell
  EXPECT_EQ(moving, 10 * kPerRing);
  EXPECT_EQ(summary.points, kRings * kPerRing);
  EXPECT_EQ(summary.motion.at("moving"), 10 * kPerRing);
  EXPECT_EQ(summary.motion.at("movable"), 20 * kPerRing);
  EXPECT_EQ(summary.motion.at("static"), 34 * kPerRing);
  EXPECT_EQ(summary.classes.at("unlabeled"), kRings * kPerRing);
  EXPECT_EQ(summary.classes.size(), 1u);
}

TEST(SemanticKittiMos, LabelsBesideVelodyneInLabelsWhenThereIsNoLabelsMos) {
  TempDir tmp;
  write_mos_scan(tmp / "08", "000000", 0, "labels");
  const auto scans = list_semantickitti_mos(tmp / "08");
  ASSERT_EQ(scans.size(), 1u);
  ASSERT_TRUE(scans[0].label.has_value());
  EXPECT_EQ(scans[0].label->filename(), "000000.label");
  const MosScan scan = read_semantickitti_mos_scan(scans[0]);
  EXPECT_EQ(scan.counts[static_cast<int>(Motion::Moving)], 10u * kPerRing);
}

TEST(SemanticKittiMos, ShortAndLongLabelFilesAreErrorsNamingTheFile) {
  for (int delta : {-1, +3}) {
    TempDir tmp;
    write_mos_scan(tmp / "08", "000560", delta);
    const std::string err = error_of([&] { import_dataset(SourceFormat::SemanticKittiMos, tmp / "08"); });
    EXPECT_NE(err.find("labels_mos/000560.label"), std::string::npos) << delta << ": " << err;
    EXPECT_NE(err.find("label count"), std::string::npos) << delta << ": " << err;
  }
}

TEST(SemanticKittiMos, ALabelOutsideStaticMovableMovingIsAnErrorNamingFileAndPoint) {
  TempDir tmp;
  write_mos_scan(tmp / "08", "000580");
  // Point 1234 gets a semantic label (40 road): the file is not a MOS label file.
  std::vector<std::uint32_t> labels(kRings * kPerRing);
  for (int i = 0; i < kRings * kPerRing; ++i) labels[i] = mos_label(i);
  labels[1234] = (3u << 16) | 40u;
  write_binary(tmp / "08/labels_mos/000580.label", labels);
  const std::string err = error_of([&] { import_dataset(SourceFormat::SemanticKittiMos, tmp / "08"); });
  EXPECT_NE(err.find("labels_mos/000580.label"), std::string::npos) << err;
  EXPECT_NE(err.find("point 1234 label"), std::string::npos) << err;
  EXPECT_NE(err.find("40"), std::string::npos) << err;
}

TEST(SemanticKittiMos, NeverGuessed) {
  TempDir tmp;
  write_mos_scan(tmp / "08", "000000");
  // Read as plain SemanticKITTI, the MOS labels are not semantic labels: the scan has none.
  const std::string err = error_of([&] { import_dataset(SourceFormat::SemanticKitti, tmp / "08"); });
  EXPECT_NE(err.find("no labelled scans"), std::string::npos) << err;
  // Semantic labels read as MOS labels are refused at the first point.
  std::vector<std::uint32_t> semantic(kRings * kPerRing, 40u);
  write_binary(tmp / "08/labels_mos/000000.label", semantic);
  const std::string mos = error_of([&] { import_dataset(SourceFormat::SemanticKittiMos, tmp / "08"); });
  EXPECT_NE(mos.find("point 0 label"), std::string::npos) << mos;
}

TEST(SemanticKittiMos, ScansWithoutLabelsAreSkippedAndCounted) {
  TempDir tmp;
  write_mos_scan(tmp / "08", "000000");
  write_mos_scan(tmp / "08", "000001");
  fs::remove(tmp / "08/labels_mos/000001.label");
  std::vector<std::string> notes;
  ImportOptions o;
  o.note = [&](const std::string& n) { notes.push_back(n); };
  const Dataset d = import_dataset(SourceFormat::SemanticKittiMos, tmp / "08", o);
  EXPECT_EQ(d.size(), 1);
  ASSERT_FALSE(notes.empty());
  EXPECT_NE(notes[0].find("skipped 1 scans without a moving-object label file"), std::string::npos) << notes[0];
  o.include_unlabelled = true;
  EXPECT_NE(error_of([&] { import_dataset(SourceFormat::SemanticKittiMos, tmp / "08", o); }).find("--include-unlabelled"),
            std::string::npos);
}

}  // namespace
}  // namespace lidarsim::data
