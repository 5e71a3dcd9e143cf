// The PCL generator against real scans: for the labelled boxes of the KITTI object sample
// (HDL-64E), the simulated returns per box next to the real points inside the same box.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>

#include "data/kitti_object.h"
#include "sensor/pcl_generator.h"
#include "sensor/scenario.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;

namespace {

// A KITTI label as an object in the Velodyne frame (box centre = bottom centre + h/2 up;
// heading = the box's length axis, (cos ry, 0, -sin ry) in the rectified camera frame).
sensor::Object to_velodyne(const data::KittiObjectLabel& l, const data::KittiCalib& calib, int id) {
  sensor::Object o;
  o.id = id;
  o.cls = sensor::object_class_from_string(l.type);
  o.material = sensor::default_material(o.cls);
  const Eigen::Vector3d bottom = calib.rect_to_velo(l.location);
  const Eigen::Vector3d ahead =
      calib.rect_to_velo(l.location + Eigen::Vector3d(std::cos(l.rotation_y), 0, -std::sin(l.rotation_y))) - bottom;
  o.heading = std::atan2(ahead.y(), ahead.x());
  o.size = {l.l, l.w, l.h};
  o.position = bottom + Eigen::Vector3d(0, 0, l.h / 2);
  return o;
}

}  // namespace

// Agreement stated, with 2048 columns (the power of two nearest KITTI's ~1900 points per ring):
//  - box-shaped objects (cars, trucks, cyclists, misc) within 50 m: simulated returns within a
//    factor of 3 of the real points in the box;
//  - beyond 50 m: the simulation never counts fewer than reality. It has no dropouts: the real
//    scan returns only 23 points in the whole 4 x 2 deg window around the car at 61 m (about
//    110 beams), so that car gets 9 real points against 73 simulated (ratio 8);
//  - pedestrians are printed, not asserted: a box is a poor silhouette of a walking person
//    (the 1.2 m long box of the pedestrian at 8.9 m is mostly empty space).
TEST(PclVsKitti, SimulatedPointsPerBoxWithinFactorThreeOfRealUpTo50mAndNotFewerBeyond) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "kitti-object-sample");
  const auto frames = data::list_kitti_object(dir);
  ASSERT_EQ(frames.size(), 3u);
  // The Velodyne sits 1.73 m above the road on KITTI's car: the road is z = -1.73 here.
  sensor::PclConfig cfg;
  cfg.ground_height = -1.73;
  cfg.lanes = false;
  sensor::PclGenerator gen1024(pgm::BeamLayout::hdl64e(1024), sensor::Pose{}, cfg);
  sensor::PclGenerator gen2048(pgm::BeamLayout::hdl64e(2048), sensor::Pose{}, cfg);
  auto map1024 = gen1024.make_map();
  auto map2048 = gen2048.make_map();

  std::printf("\n| frame | class | range (m) | real points | sim 1024 col | sim 2048 col | sim2048/real |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  int cars = 0, checked = 0;
  for (const auto& f : frames) {
    const auto scan = data::read_kitti_object_scan(f);
    const auto calib = data::read_kitti_calib(f.calib);
    std::vector<sensor::Object> objects;
    std::vector<std::size_t> label_of;
    for (std::size_t i = 0; i < scan.labels.size(); ++i) {
      if (scan.labels[i].type == "DontCare") continue;
      objects.push_back(to_velodyne(scan.labels[i], calib, static_cast<int>(i)));
      label_of.push_back(i);
    }
    gen1024.generate(objects, {}, map1024);
    gen2048.generate(objects, {}, map2048);
    for (std::size_t k = 0; k < objects.size(); ++k) {
      auto count = [&](const pgm::PolarGridMap& m) {
        const float* id = m.channel("object_id");
        std::size_t n = 0;
        for (std::size_t c = 0; c < m.cells(); ++c) n += id[c] == objects[k].id;
        return n;
      };
      const std::size_t real = scan.points_in_box[label_of[k]];
      const std::size_t s1 = count(map1024), s2 = count(map2048);
      const double ratio = real ? static_cast<double>(s2) / real : 0.0;
      std::printf("| %s | %s | %.1f | %zu | %zu | %zu | %.2f |\n", f.id.c_str(), scan.labels[label_of[k]].type.c_str(),
                  objects[k].position.head<2>().norm(), real, s1, s2, ratio);
      const double range = objects[k].position.head<2>().norm();
      if (objects[k].cls == sensor::ObjectClass::Car) ++cars;
      if (objects[k].cls == sensor::ObjectClass::Pedestrian) continue;
      if (range <= 50) {
        ++checked;
        EXPECT_GT(ratio, 1.0 / 3) << f.id << " " << scan.labels[label_of[k]].type << " at " << range << " m";
        EXPECT_LT(ratio, 3.0) << f.id << " " << scan.labels[label_of[k]].type << " at " << range << " m";
      } else {
        EXPECT_GE(s2, real) << f.id << " " << scan.labels[label_of[k]].type << " at " << range << " m";
      }
    }
  }
  EXPECT_EQ(cars, 2);
  EXPECT_EQ(checked, 3);  // cyclist 46 m, misc 9 m, car 35 m
}
