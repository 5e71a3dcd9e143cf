// The object loop's features (qualify/objects/objects.h) and what the KPI manager computes for the same
// truth object (sensor::conditional_feature on sensor::with_truth_motion, as the loop's
// re-simulation feeds it) must be the same number: a term fitted on one is applied on the other.
// A hand-made KITTI tracking sequence: a car whose centre moves unevenly in x, y and z (so a 3-D
// or one-sided acceleration differs from the BEV central difference) and whose label's
// truncation changes per frame, including KITTI tracking's level 2.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "qualify/objects/objects.h"
#include "sensor/kpi_fit.h"
#include "sensor/kpi_manager.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

// Velodyne centres of track 7 (h 1.5, w 1.6, l 4) in frames 0..3, and the label's truncated.
const Eigen::Vector3d kCentre[4] = {{10, 2, -1.0}, {11, 2.5, -0.9}, {12.5, 2.6, -0.6}, {14.5, 3.0, -0.6}};
const double kTruncated[4] = {0.3, 0, 0.55, 2};

fs::path write_sequence() {
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_loop_features_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  for (const char* sub : {"label_02", "calib", "detection/pointrcnn_Car_val"}) fs::create_directories(dir / sub);
  // R0_rect = I, Tr_velo_to_cam = the axis permutation (cam x = -y, y = -z, z = x).
  std::ofstream(dir / "calib" / "0000.txt")
      << "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n";
  std::ofstream labels(dir / "label_02" / "0000.txt");
  char line[256];
  for (int f = 0; f < 4; ++f) {
    const Eigen::Vector3d& c = kCentre[f];
    // Bottom centre in the camera frame: (-y, -z + h/2, x); heading +x (rotation_y = -pi/2).
    std::snprintf(line, sizeof line, "%d 7 Car %g 0 0 0 0 100 100 1.5 1.6 4 %.6f %.6f %.6f -1.5707963267948966\n", f,
                  kTruncated[f], -c.y(), -c.z() + 0.75, c.x());
    labels << line;
  }
  labels << "1 8 Pedestrian 0 0 0 0 0 100 100 1.8 0.6 0.8 -3 2.63 9 0\n";  // one frame: no motion
  labels.close();
  std::ofstream(dir / "detection" / "pointrcnn_Car_val" / "0000.txt")
      << "1,2,0,0,100,100,5,1.5,1.6,4,-2.5,1.65,11,-1.5707963267948966,-10\n";
  return dir;
}

}  // namespace

TEST(LoopFeatures, KpiManagerComputesTheLoopsAccelerationTruncationMotionAndBoxSizeFeatures) {
  const fs::path dir = write_sequence();
  const qualify::TrackingData data = qualify::load_tracking(dir, "", "pointrcnn", 1);
  fs::remove_all(dir);
  const qualify::ObjectSet set = qualify::collect_objects(data, {0});
  const auto motion = sensor::with_truth_motion(data.calib);
  ASSERT_EQ(set.records.size(), 5u);
  auto index = [](const std::string& name) {
    return static_cast<int>(std::find(qualify::kObjectFeatures.begin(), qualify::kObjectFeatures.end(), name) -
                            qualify::kObjectFeatures.begin());
  };
  int checked = 0;
  for (const auto& r : set.records) {
    const sensor::Object* o = nullptr;
    for (const auto& g : motion[0].frames[r.frame].truth)
      if (g.id == r.track) o = &g;
    ASSERT_NE(o, nullptr);
    const double range = o->position.head<2>().norm();
    // Every feature the KPI manager computes, except track_age (the manager counts it itself).
    for (const std::string& name : sensor::kConditionalFeatures) {
      if (name == "visibility" || name == "track_age") continue;
      EXPECT_EQ(sensor::conditional_feature(name, *o, range, 0), r.feature[index(name)])
          << name << ", track " << r.track << ", frame " << r.frame;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 5 * 12);

  // The hand-worked values. Frame 1: (p2 - 2 p1 + p0) / dt^2 = (0.5, -0.4, 0.2) / 0.01, BEV norm
  // sqrt(50^2 + 40^2) = 64.03 (3-D: 67.08); frame 2: (0.5, 0.3, 0.3) / 0.01 -> 58.31; the ends 0.
  const double acceleration[4] = {0, std::hypot(50, 40), std::hypot(50, 30), 0};
  const double truncation[4] = {0.3, 0, 0.55, 1};  // level 2 reads as 1
  for (const auto& r : set.records) {
    // Box sizes from the labels (h w l): the car 1.5 1.6 4, the pedestrian 1.8 0.6 0.8.
    const bool car = r.track == 7;
    EXPECT_DOUBLE_EQ(r.feature[index("size")], car ? 4 : 0.8);
    EXPECT_DOUBLE_EQ(r.feature[index("box_width")], car ? 1.6 : 0.6);
    EXPECT_DOUBLE_EQ(r.feature[index("box_height")], car ? 1.5 : 1.8);
    if (r.track != 7) {
      EXPECT_EQ(r.feature[index("acceleration")], 0) << "a single frame has no motion";
      continue;
    }
    EXPECT_NEAR(r.feature[index("acceleration")], acceleration[r.frame], 1e-6) << "frame " << r.frame;
    EXPECT_DOUBLE_EQ(r.feature[index("truncation")], truncation[r.frame]) << "frame " << r.frame;
  }
}
