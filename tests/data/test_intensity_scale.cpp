// Intensity scales (data/intensity_scale.h): recorded by import, kept by the dataset files, read
// as "not recorded" from older files, and lidar-train refusing to mix two recorded scales.
#include <gtest/gtest.h>
#include <hdf5.h>
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include "data/dataset.h"
#include "data/dataset_reader.h"
#include "data/import.h"
#include "tests/data/temp_dir.h"
#include "tests/support/shared_data.h"

namespace lidarsim::data {
namespace {
namespace fs = std::filesystem;
using lidarsim::testing::TempDir;

const IntensityScale kKitti = intensity_scale::kitti_reflectance();
const IntensityScale kNuscenes = intensity_scale::nuscenes_intensity();

// Two frames of 16 x 256 cells with returns everywhere (room for the guarded split's bands).
Dataset tiny_dataset(const IntensityScale& scale) {
  Dataset set;
  set.channels = {"range", "class", "material"};
  set.intensity_scale = scale;
  const auto layout = pgm::BeamLayout::uniform(16, 2.0, -24.0, 256);
  for (int f = 0; f < 2; ++f) {
    pgm::PolarGridMap map(layout, {"range", "class", "material", "intensity", "mask"});
    for (int r = 0; r < map.rows(); ++r)
      for (int c = 0; c < map.cols(); ++c) {
        map.at(0, r, c) = 4.f + r + std::sin(0.1f * c + f);
        map.at(1, r, c) = 9.f;
        map.at(2, r, c) = 1.f;
        map.at(3, r, c) = 0.3f + 0.01f * r;
        map.at(4, r, c) = 1.f;
      }
    set.append(map, "f" + std::to_string(f), "ring");
  }
  return set;
}

bool has_root_attr(const fs::path& file, const char* name) {
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const hid_t root = H5Gopen2(f, "/", H5P_DEFAULT);
  const bool has = H5Aexists(root, name) > 0;
  H5Gclose(root);
  H5Fclose(f);
  return has;
}

TEST(IntensityScale, ConflictNamesBothSetsAndIgnoresUnrecordedOnes) {
  EXPECT_EQ(intensity_scale_conflict({{"a.h5", kKitti}, {"b.h5", kKitti}}), "");
  EXPECT_EQ(intensity_scale_conflict({{"a.h5", kKitti}, {"old.h5", {}}, {"c.h5", kKitti}}), "");
  EXPECT_EQ(intensity_scale_conflict({{"old.h5", {}}, {"b.h5", kNuscenes}}), "");
  const std::string c = intensity_scale_conflict({{"a.h5", kKitti}, {"old.h5", {}}, {"b.h5", kNuscenes}});
  EXPECT_EQ(c, "a.h5 records kitti_reflectance_0_1 (as recorded); b.h5 records nuscenes_intensity_0_255 (value / 255)");
  // The same quantity normalised another way is another scale.
  EXPECT_NE(intensity_scale_conflict({{"a.h5", kNuscenes}, {"b.h5", {kNuscenes.name, "value / 256"}}}), "");
}

TEST(IntensityScale, EveryFormatRecordsOneAndKittiFormatsShareIt) {
  for (SourceFormat f : {SourceFormat::SemanticKitti, SourceFormat::KittiObject, SourceFormat::Nuscenes,
                         SourceFormat::Rellis3d, SourceFormat::Ouster, SourceFormat::NuscenesLidarseg,
                         SourceFormat::SemanticKittiMos})
    EXPECT_TRUE(intensity_scale_of(f).recorded()) << to_string(f);
  EXPECT_EQ(intensity_scale_of(SourceFormat::SemanticKittiMos), intensity_scale_of(SourceFormat::SemanticKitti));
  EXPECT_EQ(intensity_scale_of(SourceFormat::KittiObject), intensity_scale_of(SourceFormat::SemanticKitti));
  EXPECT_EQ(intensity_scale_of(SourceFormat::NuscenesLidarseg), intensity_scale_of(SourceFormat::Nuscenes));
  EXPECT_NE(intensity_scale_of(SourceFormat::Ouster), intensity_scale_of(SourceFormat::SemanticKitti));
  EXPECT_NE(intensity_scale_of(SourceFormat::Rellis3d), intensity_scale_of(SourceFormat::Ouster));
}

TEST(IntensityScale, WrittenAsAttributesAndReadBackOlderFilesHaveNone) {
  TempDir tmp;
  write_dataset(tmp / "n.h5", tiny_dataset(kNuscenes));
  EXPECT_TRUE(has_root_attr(tmp / "n.h5", "intensity_scale"));
  EXPECT_EQ(read_dataset(tmp / "n.h5").intensity_scale, kNuscenes);
  EXPECT_EQ(DatasetReader(tmp / "n.h5").header().intensity_scale, kNuscenes);
  // A dataset that does not know its scale writes no attribute, as files did before it existed.
  write_dataset(tmp / "old.h5", tiny_dataset({}));
  EXPECT_FALSE(has_root_attr(tmp / "old.h5", "intensity_scale"));
  const Dataset old = read_dataset(tmp / "old.h5");
  EXPECT_FALSE(old.intensity_scale.recorded());
  EXPECT_EQ(old.intensity_scale.describe(), "not recorded");
}

TEST(IntensityScale, ImportRecordsTheFormatsScale) {
  TempDir tmp;
  const fs::path samples = lidarsim::testing::source_dir() / "data/samples/semantickitti";
  const ImportSummary s = import_to_file(SourceFormat::SemanticKitti, samples, tmp / "sk.h5");
  EXPECT_EQ(s.intensity_scale, kKitti);
  EXPECT_EQ(DatasetReader(tmp / "sk.h5").header().intensity_scale, kKitti);
}

// --- lidar-train ---------------------------------------------------------------------------------

struct TrainRun {
  int code = -1;
  std::string output;
};

fs::path train_exe() { return lidarsim::testing::binary_dir() / "train" / "lidar-train"; }

TrainRun train(const std::string& args) {
  TrainRun r;
  const std::string cmd = train_exe().string() + " --quiet --base 4 --depth 2 --epochs 1 --steps-per-epoch 1 --threads 1 " +
                          args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  while (std::fgets(buf.data(), buf.size(), p)) r.output += buf.data();
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

TEST(IntensityScale, LidarTrainRefusesToMixRecordedScalesUnlessTold) {
  if (!fs::exists(train_exe())) {
    if (lidarsim::testing::running_in_ci()) FAIL() << "lidar-train not built: " << train_exe();
    GTEST_SKIP() << "build the lidar-train target first: " << train_exe();
  }
  TempDir tmp;
  const std::string k = (tmp / "kitti.h5").string(), k2 = (tmp / "kitti2.h5").string(),
                    n = (tmp / "nuscenes.h5").string(), old = (tmp / "old.h5").string(), out = (tmp / "ck.h5").string();
  write_dataset(k, tiny_dataset(kKitti));
  write_dataset(k2, tiny_dataset(kKitti));
  write_dataset(n, tiny_dataset(kNuscenes));
  write_dataset(old, tiny_dataset({}));
  for (const std::string& mix : {"--data " + k + "," + n, "--data " + k + " --train-also " + n, "--data " + k + " --val " + n}) {
    const TrainRun r = train(mix + " --out " + out);
    EXPECT_EQ(r.code, 1) << mix << "\n" << r.output;
    EXPECT_EQ(r.output.rfind("error: lidar-train: intensity scales differ", 0), 0u) << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
    for (const std::string& must : {k, n, std::string("kitti_reflectance_0_1"), std::string("nuscenes_intensity_0_255"),
                                    std::string("--mix-intensity-scales")})
      EXPECT_NE(r.output.find(must), std::string::npos) << must << " missing in: " << r.output;
    EXPECT_FALSE(fs::exists(out));
  }
  // Told to mix, same scales, or a file without a recorded scale: training runs.
  for (const std::string& ok : {"--data " + k + "," + n + " --mix-intensity-scales", "--data " + k + "," + k2,
                                "--data " + k + "," + old, "--data " + old + " --val " + n}) {
    const TrainRun r = train(ok + " --out " + out);
    EXPECT_EQ(r.code, 0) << ok << "\n" << r.output;
    EXPECT_TRUE(fs::exists(out)) << ok;
    fs::remove(out);
  }
}

}  // namespace
}  // namespace lidarsim::data
