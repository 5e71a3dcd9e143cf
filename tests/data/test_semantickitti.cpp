#include <gtest/gtest.h>

#include "common/error.h"
#include "data/semantickitti.h"
#include "pgm/materials.h"
#include "tests/support/shared_data.h"
#include "tests/data/temp_dir.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;
using lidarsim::testing::write_binary;

namespace {
void make_scan(const std::filesystem::path& seq, const std::string& id, bool with_label) {
  write_binary(seq / "velodyne" / (id + ".bin"), std::vector<float>{1, 0, 0, 0.1f, 0, 1, 0, 0.2f});
  if (with_label) write_binary(seq / "labels" / (id + ".label"), std::vector<std::uint32_t>{(7u << 16) | 10u, 60u});
}
}  // namespace

TEST(SemanticKitti, AcceptsRootSequencesAndSingleSequenceLayouts) {
  TempDir dir;
  make_scan(dir / "root/sequences/00", "000001", true);
  make_scan(dir / "root/sequences/00", "000000", true);
  make_scan(dir / "root/sequences/01", "000000", false);
  const auto all = data::list_semantickitti(dir / "root");
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].sequence, "00");
  EXPECT_EQ(all[0].id, "000000");  // sorted
  EXPECT_FALSE(all[2].label.has_value());
  EXPECT_EQ(data::list_semantickitti(dir / "root", {"01"}).size(), 1u);
  EXPECT_EQ(data::list_semantickitti(dir / "root/sequences").size(), 3u);
  EXPECT_EQ(data::list_semantickitti(dir / "root/sequences/00/").size(), 2u);
  EXPECT_THROW(data::list_semantickitti(dir / "root/sequences/00/velodyne"), Error);
}

TEST(SemanticKitti, LabelsGiveClassFromLower16BitsAndDefaultMaterial) {
  TempDir dir;
  make_scan(dir.path(), "000000", true);
  const auto files = data::list_semantickitti(dir.path());
  const auto scan = data::read_semantickitti_scan(files.at(0));
  ASSERT_EQ(scan.points.size(), 2u);
  EXPECT_EQ(scan.points[0].class_id, pgm::cls::car);  // instance id in the upper bits ignored
  EXPECT_EQ(scan.points[0].material_id, pgm::material::car_paint);
  EXPECT_EQ(scan.points[1].class_id, pgm::cls::lane_marking);
  EXPECT_EQ(scan.points[1].material_id, pgm::material::lane_paint);
  EXPECT_EQ(scan.sources.size(), 2u);
}

TEST(SemanticKitti, LabelCountMismatchNamesTheLabelFile) {
  TempDir dir;
  make_scan(dir.path(), "000000", false);
  write_binary(dir / "labels/000000.label", std::vector<std::uint32_t>{10});
  const auto files = data::list_semantickitti(dir.path());
  try {
    data::read_semantickitti_scan(files.at(0));
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("000000.label: label count"), std::string::npos) << e.what();
  }
}

// The reference convention: rows cut where the stored azimuth wraps, exactly 64 per scan.
TEST(SemanticKittiReal, EveryScanCutsIntoExactly64FiringOrderRows) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "semantickitti-seq00-sample");
  const auto files = data::list_semantickitti(dir);
  ASSERT_EQ(files.size(), 6u);
  int labelled = 0;
  for (const auto& f : files) {
    const auto scan = data::read_semantickitti_scan(f);
    std::vector<int> rows;
    EXPECT_EQ(pgm::firing_order_rows(scan.points, rows), 64) << f.bin;
    const auto res = pgm::project(scan.points, pgm::BeamLayout::hdl64e(1024));
    EXPECT_EQ(res.row_mode, pgm::RowMode::FiringOrder) << f.bin;
    EXPECT_EQ(res.dropped, 0u);
    labelled += f.label.has_value();
    if (f.label) {
      EXPECT_EQ(scan.unknown_labels, 0u);
    }
  }
  EXPECT_EQ(labelled, 3);
}

// The scan bundled for the demo (no ../shared needed) reads as a labelled 64-row scan.
TEST(SemanticKittiBundled, SampleScanHasLabelsAnd64FiringOrderRows) {
  const auto dir = lidarsim::testing::source_dir() / "data/samples/semantickitti";
  const auto files = data::list_semantickitti(dir);
  ASSERT_EQ(files.size(), 1u);
  ASSERT_TRUE(files[0].label.has_value());
  const auto scan = data::read_semantickitti_scan(files[0]);
  EXPECT_EQ(scan.points.size(), 124668u);  // SOURCE.md's count for 000000
  std::vector<int> rows;
  EXPECT_EQ(pgm::firing_order_rows(scan.points, rows), 64);
  std::size_t cars = 0;
  for (const auto& p : scan.points) cars += p.class_id == pgm::cls::car;
  EXPECT_EQ(cars, 4234u);  // SOURCE.md: car 4234 points in 000000
}
