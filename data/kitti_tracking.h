#pragma once
// KITTI tracking ground truth (label_02/NNNN.txt + calib/NNNN.txt) and detections in the
// AB3DMOT text layout (detection/<name>_{Car,Pedestrian,Cyclist}_val/NNNN.txt), read as they
// are and converted to the Velodyne frame (ISO 8855: x forward, y left, z up) with box centres
// (KITTI stores the bottom centre in the rectified camera frame: centre = bottom + h/2 up).
//
// label_02 columns: frame track_id type truncated occluded alpha l t r b h w l x y z rotation_y
// (track_id -1 and type DontCare have no 3D box and are skipped).
// AB3DMOT columns (comma separated): frame, type_id (1 Pedestrian, 2 Car, 3 Cyclist),
// x1, y1, x2, y2, score (a logit, may be negative), h, w, l, x, y, z, rot_y, alpha.
#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <vector>

#include "data/kitti_object.h"
#include "sensor/kpi_fit.h"
#include "sensor/scene.h"

namespace lidarsim::data {

struct KittiTrackingObject {
  int frame = 0;
  sensor::Object object;  // Velodyne frame; id = track id (truth) or line index (detection)
  std::string type;       // KITTI type: Car, Van, Truck, Pedestrian, Person_sitting, Cyclist, Tram, Misc
  int occluded = 0;       // KITTI occlusion level 0 visible, 1 partly, 2 largely, 3 unknown (truth)
  double truncated = 0;   // as in the label (truth): a level 0, 1, 2 in KITTI tracking, a share 0..1 in the
                          // object benchmark; object.truncation holds it clamped to [0, 1]
};

struct KittiTrackingFrame {
  int frame = 0;
  std::vector<KittiTrackingObject> truth;       // DontCare skipped
  std::vector<KittiTrackingObject> detections;  // every class and score, as in the files
};

struct KittiTrackingSequence {
  std::string name;  // "0001"
  KittiCalib calib;
  std::vector<KittiTrackingFrame> frames;  // frames[i].frame == i, 0 .. last frame in any file
};

// Box in the rectified camera frame -> Object in the Velodyne frame.
struct KittiBoxConverter {
  explicit KittiBoxConverter(const KittiCalib& calib);
  // h, w, l (m), bottom centre (rectified camera), rotation_y (about camera y, down).
  sensor::Object convert(double h, double w, double l, const Eigen::Vector3d& bottom, double rotation_y) const;
  Eigen::Matrix3d rect_to_velo_rotation;
  Eigen::Vector3d rect_to_velo_translation;
};

sensor::ObjectClass kitti_type_to_class(const std::string& type);  // throws for unknown types

// Readers; each malformed line is an error "file: line N: what was expected".
std::vector<KittiTrackingObject> read_kitti_tracking_labels(const std::filesystem::path& path,
                                                            const KittiBoxConverter& conv);
std::vector<KittiTrackingObject> read_ab3dmot_detections(const std::filesystem::path& path,
                                                         const KittiBoxConverter& conv);
// Sequence names listed in an evaluate_tracking.seqmap file (first column).
std::vector<std::string> read_kitti_seqmap(const std::filesystem::path& path);

// root holds label_02/, calib/ and (optionally) detection/<detector>_<Class>_val/.
// Detection files that do not exist give no detections for that class.
KittiTrackingSequence read_kitti_tracking_sequence(const std::filesystem::path& root, const std::string& name,
                                                   const std::string& detector = "pointrcnn");

// For the KPI calibration: truth = Car, Pedestrian, Cyclist (exact KITTI types, visible
// fraction = (1.0, 0.6, 0.2 for occlusion level 0, 1, 2-3) x (1 - truncation), truncation = the
// label's truncated clamped to [0, 1]); every other type (Van, Truck, Person_sitting, Tram, Misc)
// goes to `others`, so a Car detection on a Van is not counted as a false positive; all
// detections are kept (the fit applies its score threshold).
sensor::CalibrationSequence to_calibration_sequence(const KittiTrackingSequence& seq);

}  // namespace lidarsim::data
