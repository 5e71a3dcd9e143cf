// KITTI tracking labels + calib and AB3DMOT detections: the camera -> Velodyne conversion on a
// hand-worked case, malformed lines named by file and line, and the real validation data.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>

#include "common/error.h"
#include "data/kitti_tracking.h"
#include "tests/support/shared_data.h"
#include "tests/support/temp_path.h"

#include <functional>
#include "common/angles.h"

namespace lidarsim::data {
namespace {

namespace fs = std::filesystem;
using lidarsim::kPi;

// The textbook mounting: camera x = -velo y, camera y = -velo z, camera z = velo x, plus a
// translation t (x_cam = R x_velo + t), R0_rect = identity.
KittiCalib axis_calib(const Eigen::Vector3d& t = Eigen::Vector3d::Zero()) {
  KittiCalib c;
  c.R0_rect.setIdentity();
  c.Tr_velo_to_cam << 0, -1, 0, t.x(),
                      0, 0, -1, t.y(),
                      1, 0, 0, t.z();
  return c;
}

fs::path write(const std::string& name, const std::string& text) {
  const fs::path p = lidarsim::testing::temp_path("test_kitti_tracking_" + name);
  std::ofstream(p) << text;
  return p;
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(KittiTracking, ConvertsBottomCentreInCameraToBoxCentreInVelodyne) {
  const KittiBoxConverter conv(axis_calib());
  // Bottom centre 10 m ahead, 2 m right, 1.5 m below the camera; h = 1.5 -> centre 0.75 m up.
  const sensor::Object o = conv.convert(1.5, 1.6, 4.0, {2, 1.5, 10}, -kPi / 2);
  EXPECT_NEAR(o.position.x(), 10, 1e-12);
  EXPECT_NEAR(o.position.y(), -2, 1e-12);
  EXPECT_NEAR(o.position.z(), -0.75, 1e-12);
  EXPECT_NEAR(o.size.x(), 4.0, 1e-12);  // length, width, height
  EXPECT_NEAR(o.size.y(), 1.6, 1e-12);
  EXPECT_NEAR(o.size.z(), 1.5, 1e-12);
  EXPECT_NEAR(o.heading, 0, 1e-12) << "rotation_y = -pi/2 faces camera z = Velodyne x";
  EXPECT_NEAR(conv.convert(1, 1, 1, {0, 0, 5}, 0).heading, -kPi / 2, 1e-12) << "rotation_y = 0 faces camera x = right";
  // With a translation: x_velo = R^T (x_cam - t).
  const KittiBoxConverter shifted(axis_calib({0.1, -0.2, 0.3}));
  const sensor::Object s = shifted.convert(2, 1, 1, {0, 1, 10}, 0);  // centre (0, 0, 10) in camera
  EXPECT_NEAR(s.position.x(), 10 - 0.3, 1e-12);
  EXPECT_NEAR(s.position.y(), 0.1, 1e-12);
  EXPECT_NEAR(s.position.z(), -0.2, 1e-12);
}

TEST(KittiTracking, ReadsLabelsSkippingDontCareAndDetectionsWithScores) {
  const KittiBoxConverter conv(axis_calib());
  const auto labels = write("labels.txt",
                            "0 -1 DontCare -1 -1 -10 1 2 3 4 -1 -1 -1 -1000 -1000 -1000 -10\n"
                            "0 3 Car 0.25 1 -1.5 100 150 200 250 1.5 1.6 4.0 2 1.5 10 -1.5707963267948966\n"
                            "1 4 Pedestrian 0 2 0.2 10 20 30 40 1.8 0.6 0.8 -1 1.7 6 0\n"
                            "2 5 Cyclist 2 0 0.2 10 20 30 40 1.8 0.6 0.8 -1 1.7 6 0\n");
  const auto t = read_kitti_tracking_labels(labels, conv);
  ASSERT_EQ(t.size(), 3u);
  EXPECT_EQ(t[0].frame, 0);
  EXPECT_EQ(t[0].object.id, 3);
  EXPECT_EQ(t[0].object.cls, sensor::ObjectClass::Car);
  EXPECT_EQ(t[0].occluded, 1);
  EXPECT_NEAR(t[0].object.visible_fraction, 0.6 * 0.75, 1e-12) << "occlusion 1 and 25 % truncated";
  EXPECT_DOUBLE_EQ(t[0].object.truncation, 0.25) << "the label's share, on the object";
  EXPECT_DOUBLE_EQ(t[1].object.truncation, 0);
  // KITTI tracking's truncation level 2 (a level, not a share): clamped to 1, as the visible
  // fraction has always read it.
  EXPECT_DOUBLE_EQ(t[2].truncated, 2);
  EXPECT_DOUBLE_EQ(t[2].object.truncation, 1);
  EXPECT_DOUBLE_EQ(t[2].object.visible_fraction, 0);
  EXPECT_NEAR(t[0].object.position.x(), 10, 1e-12);
  EXPECT_EQ(t[1].object.cls, sensor::ObjectClass::Pedestrian);
  EXPECT_NEAR(t[1].object.position.y(), 1, 1e-12);

  const auto dets = write("dets.txt",
                          "0,2,1,2,3,4,-0.5,1.5,1.6,4.0,2,1.5,10,-1.5707963267948966,0\n"
                          "2,1,1,2,3,4,3.25,1.8,0.6,0.8,-1,1.7,6,0,0\n");
  const auto d = read_ab3dmot_detections(dets, conv);
  ASSERT_EQ(d.size(), 2u);
  EXPECT_EQ(d[0].object.cls, sensor::ObjectClass::Car);
  EXPECT_DOUBLE_EQ(d[0].object.score, -0.5) << "negative logits are kept";
  EXPECT_EQ(d[1].frame, 2);
  EXPECT_EQ(d[1].object.cls, sensor::ObjectClass::Pedestrian);
  EXPECT_NEAR(d[1].object.position.z(), -0.8, 1e-12);
}

TEST(KittiTracking, MalformedLinesNameFileAndLine) {
  const KittiBoxConverter conv(axis_calib());
  const std::string ok = "0 3 Car 0 0 -1.5 1 2 3 4 1.5 1.6 4.0 2 1.5 10 0\n";
  auto label_error = [&](const std::string& name, const std::string& bad) {
    const auto p = write(name, ok + bad);
    return std::make_pair(p.string(), error_of([&] { read_kitti_tracking_labels(p, conv); }));
  };
  auto [f1, e1] = label_error("short.txt", "1 3 Car 0 0 -1.5 1 2 3 4 1.5 1.6 4.0 2 1.5 10\n");
  EXPECT_NE(e1.find(f1 + ": line 2: expected 17 space-separated fields"), std::string::npos) << e1;
  EXPECT_NE(e1.find("got 16"), std::string::npos) << e1;
  auto [f2, e2] = label_error("nan.txt", "1 3 Car 0 0 -1.5 1 2 3 4 1.5 1.6 4.0 nan 1.5 10 0\n");
  EXPECT_NE(e2.find(f2 + ": line 2: x: must be finite"), std::string::npos) << e2;
  auto [f3, e3] = label_error("word.txt", "1 3 Car 0 0 -1.5 1 2 3 4 1.5 abc 4.0 2 1.5 10 0\n");
  EXPECT_NE(e3.find(f3 + ": line 2: w: expected a number, got \"abc\""), std::string::npos) << e3;
  auto [f4, e4] = label_error("type.txt", "1 3 Spaceship 0 0 -1.5 1 2 3 4 1.5 1.6 4.0 2 1.5 10 0\n");
  EXPECT_NE(e4.find(f4 + ": line 2: type: unknown KITTI type \"Spaceship\""), std::string::npos) << e4;
  auto [f5, e5] = label_error("size.txt", "1 3 Car 0 0 -1.5 1 2 3 4 -1.5 1.6 4.0 2 1.5 10 0\n");
  EXPECT_NE(e5.find(f5 + ": line 2: box size h, w, l: must be positive"), std::string::npos) << e5;

  const auto d = write("baddet.txt", "0,2,1,2,3,4,0.5,1.5,1.6,4.0,2,1.5,10,0,0\n0,2,1,2,3,4,0.5,1.5,1.6\n");
  const std::string ed = error_of([&] { read_ab3dmot_detections(d, conv); });
  EXPECT_NE(ed.find(d.string() + ": line 2: expected 15 comma-separated fields"), std::string::npos) << ed;
  const auto t = write("badtype.txt", "0,7,1,2,3,4,0.5,1.5,1.6,4.0,2,1.5,10,0,0\n");
  EXPECT_NE(error_of([&] { read_ab3dmot_detections(t, conv); }).find("line 1: type_id: expected 1 (Pedestrian)"),
            std::string::npos);
  EXPECT_NE(error_of([&] { read_ab3dmot_detections("/nonexistent/0001.txt", conv); }).find("/nonexistent/0001.txt: (file)"),
            std::string::npos);
}

TEST(KittiTracking, RealValidationSequenceMatchesItsDocumentedShape) {
  LIDARSIM_REQUIRE_SHARED_DATA(root, "kitti-tracking-gt-pointrcnn");
  const auto names = read_kitti_seqmap(root / "evaluate_tracking.seqmap.val");
  EXPECT_EQ(names.size(), 11u);  // SOURCE.md: 1, 6, 8, 10, 12, 13, 14, 15, 16, 18, 19
  const KittiTrackingSequence seq = read_kitti_tracking_sequence(root, "0001");
  EXPECT_EQ(seq.frames.size(), 447u) << "SOURCE.md: 447 frames in sequence 0001";
  // Matched cars lie close to their detections (SOURCE.md: median 0.10 m on the val split),
  // which only holds if both went through the same, correct camera -> Velodyne conversion.
  const auto cal = to_calibration_sequence(seq);
  std::vector<double> d;
  for (const auto& fr : cal.frames) {
    const auto m = sensor::match_truth_to_detections(fr.truth, fr.detections, 2.0, 0.0);
    for (size_t i = 0; i < m.size(); ++i)
      if (m[i] >= 0 && fr.truth[i].cls == sensor::ObjectClass::Car)
        d.push_back((fr.truth[i].position - fr.detections[m[i]].position).head<2>().norm());
    for (const auto& o : fr.truth) {
      EXPECT_GT(o.position.x(), -5) << "KITTI labels are in front of the car (camera view)";
      EXPECT_LT(o.position.z(), 2.0) << "box centres are near the ground, sensor at ~1.7 m";
    }
  }
  ASSERT_GT(d.size(), 500u);
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  EXPECT_LT(d[d.size() / 2], 0.2);
}

}  // namespace
}  // namespace lidarsim::data
