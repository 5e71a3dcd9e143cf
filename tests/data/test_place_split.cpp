// Held out by place (data/place_split.h, bench_intensity_places, scripts/intensity_places.sh):
// synthetic datasets written to files with their /place_* attributes; for every fold, no frame of
// the held-out place may be in a training set, frames of one place split across two files are held
// out together, and only sets on the same grid and intensity scale train.
#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>

#include "common/error.h"
#include "data/dataset.h"
#include "data/intensity_scale.h"
#include "data/place_split.h"
#include "pgm/projection.h"
#include "tests/data/temp_dir.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;

namespace {

// Frames at `places` on a rows x cols grid, recorded on `scale`, written to dir/name.h5.
data::PlacedSet write_set(const TempDir& dir, const std::string& name, const std::vector<data::FramePlace>& places,
                          int rows, int cols, const data::IntensityScale& scale) {
  const auto layout = pgm::BeamLayout::uniform(rows, 2, -2, cols);
  data::Dataset d;
  d.channels = {"range", "class", "material"};
  d.source_format = "test";
  d.intensity_scale = scale;
  for (std::size_t f = 0; f < places.size(); ++f) {
    pgm::Point p;
    p.x = 5.f + f, p.y = 1, p.z = 0, p.intensity = 0.25f, p.class_id = 9, p.material_id = 1;
    pgm::ProjectOptions o;
    o.row_mode = pgm::RowMode::NearestElevation;
    d.append(pgm::project({p}, layout, o).pgm, name + "_" + std::to_string(f), "nearest_elevation", places[f]);
    d.sources.push_back(name + std::to_string(f) + ".bin");
  }
  data::write_dataset(dir / (name + ".h5"), d);
  return data::read_placed_set(name, dir / (name + ".h5"));
}

const data::PlaceFold& fold_of(const std::vector<data::PlaceFold>& folds, const std::string& held) {
  for (const auto& f : folds)
    if (f.held_out == held) return f;
  throw Error("no fold " + held);
}

// The places the files of a fold's training sets hold, read back from the files.
std::set<std::string> training_places(const data::PlaceFold& f, const TempDir& dir) {
  std::set<std::string> keys;
  for (const auto& name : f.training)
    for (const auto& p : data::read_placed_set(name, dir / (name + ".h5")).places) keys.insert(data::place_key(p));
  return keys;
}

}  // namespace

TEST(PlaceSplit, NoFoldTrainsOnItsHeldOutPlace) {
  TempDir dir;
  const auto kitti = data::intensity_scale::kitti_reflectance(), nus = data::intensity_scale::nuscenes_intensity();
  std::vector<data::PlacedSet> sets = {
      write_set(dir, "seq00", {{"semantickitti", "00", "0"}, {"semantickitti", "00", "1"}, {"semantickitti", "00", "2"}}, 8, 32, kitti),
      write_set(dir, "seq08", {{"semantickitti", "08", "0"}, {"semantickitti", "08", "1"}}, 8, 32, kitti),
      write_set(dir, "kitti_object", {{"kitti_object", "", "000000"}, {"kitti_object", "", "000003"}}, 8, 32, kitti),
      // The rest of sequence 00 in another file: held out with seq00, never trained on beside it.
      write_set(dir, "seq00_more", {{"semantickitti", "00", "3"}, {"semantickitti", "00", "4"}}, 8, 32, kitti),
      write_set(dir, "nuscenes", {{"nuscenes", "scene-0061", "0"}, {"nuscenes", "scene-0061", "1"}}, 4, 32, nus),
      write_set(dir, "rellis3d", {{"rellis3d", "", "000104"}}, 8, 64, data::intensity_scale::rellis3d_reflectivity()),
  };
  const auto folds = data::place_folds(sets);
  ASSERT_EQ(folds.size(), sets.size());
  for (std::size_t i = 0; i < sets.size(); ++i) {
    const auto& f = fold_of(folds, sets[i].name);
    const auto trained = training_places(f, dir);
    for (const auto& p : sets[i].places)
      EXPECT_EQ(trained.count(data::place_key(p)), 0u) << sets[i].name << " held out, trained on its place " << data::place_key(p);
    EXPECT_EQ(std::count(f.training.begin(), f.training.end(), f.held_out), 0) << f.held_out;
    EXPECT_EQ(f.training.size() + f.excluded.size(), sets.size() - 1) << f.held_out;
  }
  EXPECT_EQ(fold_of(folds, "seq00").training, (std::vector<std::string>{"seq08", "kitti_object"}));
  EXPECT_EQ(fold_of(folds, "seq08").training, (std::vector<std::string>{"seq00", "kitti_object", "seq00_more"}));
  EXPECT_EQ(fold_of(folds, "kitti_object").training, (std::vector<std::string>{"seq00", "seq08", "seq00_more"}));
  EXPECT_TRUE(fold_of(folds, "nuscenes").training.empty());  // another grid and scale
  EXPECT_TRUE(fold_of(folds, "rellis3d").training.empty());
  const auto& ex = fold_of(folds, "seq00").excluded;
  ASSERT_EQ(ex.size(), 3u);
  EXPECT_NE(ex[0].find("seq00_more: holds frames of the held-out place semantickitti/00"), std::string::npos) << ex[0];
  EXPECT_NE(ex[1].find("nuscenes: grid 4 x 32"), std::string::npos) << ex[1];
  EXPECT_NE(ex[2].find("rellis3d: grid 8 x 64"), std::string::npos) << ex[2];
}

TEST(PlaceSplit, SameGridOtherScaleDoesNotTrain) {
  TempDir dir;
  const auto a = write_set(dir, "a", {{"semantickitti", "00", "0"}}, 8, 32, data::intensity_scale::kitti_reflectance());
  const auto b = write_set(dir, "b", {{"ouster", "x", "0"}}, 8, 32, data::intensity_scale::ouster_reflectivity());
  const auto folds = data::place_folds({a, b});
  EXPECT_TRUE(folds[0].training.empty());
  ASSERT_EQ(folds[0].excluded.size(), 1u);
  EXPECT_NE(folds[0].excluded[0].find("intensity scale"), std::string::npos) << folds[0].excluded[0];
}

TEST(PlaceSplit, LeakCheckNamesTheFrame) {
  TempDir dir;
  const auto kitti = data::intensity_scale::kitti_reflectance();
  const auto held = write_set(dir, "seq08", {{"semantickitti", "08", "0"}}, 8, 32, kitti);
  const auto mixed = write_set(dir, "mixed", {{"semantickitti", "00", "0"}, {"semantickitti", "08", "7"}}, 8, 32, kitti);
  const auto clean = write_set(dir, "clean", {{"semantickitti", "00", "1"}}, 8, 32, kitti);
  EXPECT_NO_THROW(data::check_no_place_leak(held, {clean}));
  const std::string msg = lidarsim::testing::error_of([&] { data::check_no_place_leak(held, {clean, mixed}); });
  EXPECT_NE(msg.find("mixed"), std::string::npos) << msg;
  EXPECT_NE(msg.find("frame 1 (7)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("semantickitti/08"), std::string::npos) << msg;
  // The fold planner never offers the mixed set for seq08.
  const auto folds = data::place_folds({held, mixed, clean});
  EXPECT_EQ(folds[0].training, (std::vector<std::string>{"clean"}));
}

TEST(PlaceSplit, DuplicateNamesAndEmptySetsAreErrors) {
  TempDir dir;
  const auto a = write_set(dir, "a", {{"semantickitti", "00", "0"}}, 8, 32, data::intensity_scale::kitti_reflectance());
  EXPECT_THROW(data::place_folds({a, a}), Error);
  data::PlacedSet empty{"e", "e.h5", {}, 8, 32, {}};
  EXPECT_THROW(data::place_folds({a, empty}), Error);
}
