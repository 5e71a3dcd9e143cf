#pragma once
// KITTI object benchmark, read as it is: a `training`-style folder with velodyne/XXXXXX.bin,
// label_2/XXXXXX.txt and calib/XXXXXX.txt.
//
// Class per point from the 3D boxes: a point gets the class of the box that contains it
// (pgm::class_from_object_type; the first box in the file wins where boxes overlap). Points
// outside every box are background: class pgm::cls::unlabeled, material unknown. KITTI labels
// only objects seen by the front camera, so objects behind the car are background too.
// DontCare lines have no 3D box and label no points.
#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <vector>

#include "data/semantickitti.h"

namespace lidarsim::data {

struct KittiCalib {
  Eigen::Matrix3d R0_rect = Eigen::Matrix3d::Identity();
  Eigen::Matrix<double, 3, 4> Tr_velo_to_cam = Eigen::Matrix<double, 3, 4>::Zero();
  Eigen::Matrix<double, 3, 4> P2 = Eigen::Matrix<double, 3, 4>::Zero();
  // x_rect = R0_rect * Tr_velo_to_cam * [x_velo; 1]
  Eigen::Vector3d velo_to_rect(const Eigen::Vector3d& p) const;
  Eigen::Vector3d rect_to_velo(const Eigen::Vector3d& p) const;
};
// Reads "KEY: v v v ..." lines; R0_rect and Tr_velo_to_cam are required ("R0" and
// "Tr_velo_cam", as KITTI tracking spells them, are accepted too).
KittiCalib read_kitti_calib(const std::filesystem::path& path);

struct KittiObjectLabel {
  std::string type;  // "Car", "Pedestrian", ..., "DontCare"
  double truncated = 0, occluded = 0, alpha = 0;
  double bbox[4] = {0, 0, 0, 0};  // left, top, right, bottom (px)
  double h = 0, w = 0, l = 0;     // metres
  Eigen::Vector3d location = Eigen::Vector3d::Zero();  // bottom centre, rectified camera frame
  double rotation_y = 0;
  // True when p (rectified camera frame: x right, y down, z forward) lies inside the box.
  bool contains_rect(const Eigen::Vector3d& p) const;
};
// One object per line, 15 fields (a 16th, score, is allowed); every number must be finite.
// More than kManyKittiObjects lines print a warning with the count and the file on stderr: real
// KITTI frames list fewer than 100 objects, so such a file is likely generated or corrupt. It
// is still read (augmented or simulated scenes may hold that many, and the box index below
// keeps their import to seconds).
inline constexpr std::size_t kManyKittiObjects = 1000;
std::vector<KittiObjectLabel> read_kitti_object_labels(const std::filesystem::path& path);

struct KittiObjectFrame {
  std::string id;  // "000000"
  std::filesystem::path bin, label, calib;
};
// Frames of a training-style folder (DIR/velodyne, DIR/label_2, DIR/calib, or DIR/training/...),
// sorted by id; frames lacking a label or calib file are an error naming the missing file.
std::vector<KittiObjectFrame> list_kitti_object(const std::filesystem::path& dir);

// Points with class and material from the boxes; `points_in_box[i]` counts points of label i.
struct KittiObjectScan {
  std::vector<pgm::Point> points;
  std::vector<KittiObjectLabel> labels;
  std::vector<std::size_t> points_in_box;
  std::vector<std::filesystem::path> sources;
};
KittiObjectScan read_kitti_object_scan(const KittiObjectFrame& frame);

// Sets each point's class (and default material) to that of the first label in file order whose
// box contains it (contains_rect in the rectified frame), unlabeled/unknown outside every box;
// returns the points per label. Candidates come from a grid over the boxes' bird's-eye
// footprints, so the cost grows with the boxes near a point rather than with all boxes; the
// result equals testing every box in file order.
std::vector<std::size_t> label_points_from_boxes(std::vector<pgm::Point>& points, const KittiCalib& calib,
                                                 const std::vector<KittiObjectLabel>& labels);

}  // namespace lidarsim::data
