#include "data/kitti_tracking.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "common/error.h"
#include "data/plausibility.h"

namespace lidarsim::data {

namespace fs = std::filesystem;
using sensor::Object;
using sensor::ObjectClass;

KittiBoxConverter::KittiBoxConverter(const KittiCalib& calib) {
  // x_rect = R0 (A x_velo + b)  =>  x_velo = A^-1 (R0^-1 x_rect - b)
  const Eigen::Matrix3d A = calib.Tr_velo_to_cam.leftCols<3>();
  const Eigen::Vector3d b = calib.Tr_velo_to_cam.col(3);
  const Eigen::Matrix3d A_inv = A.inverse();
  rect_to_velo_rotation = A_inv * calib.R0_rect.inverse();
  rect_to_velo_translation = -A_inv * b;
}

Object KittiBoxConverter::convert(double h, double w, double l, const Eigen::Vector3d& bottom,
                                  double rotation_y) const {
  Object o;
  const Eigen::Vector3d centre_rect = bottom - Eigen::Vector3d(0, h / 2, 0);  // camera y points down
  o.position = rect_to_velo_rotation * centre_rect + rect_to_velo_translation;
  // The box's forward axis in the camera frame is (cos ry, 0, -sin ry).
  const Eigen::Vector3d fwd = rect_to_velo_rotation * Eigen::Vector3d(std::cos(rotation_y), 0, -std::sin(rotation_y));
  o.heading = std::atan2(fwd.y(), fwd.x());
  o.size = Eigen::Vector3d(l, w, h);
  return o;
}

ObjectClass kitti_type_to_class(const std::string& t) {
  if (t == "Car") return ObjectClass::Car;
  if (t == "Van") return ObjectClass::Van;
  if (t == "Truck") return ObjectClass::Truck;
  if (t == "Pedestrian" || t == "Person_sitting" || t == "Person") return ObjectClass::Pedestrian;
  if (t == "Cyclist") return ObjectClass::Cyclist;
  if (t == "Tram" || t == "Misc") return ObjectClass::Misc;
  throw Error("unknown KITTI type \"" + t + "\"");
}

namespace {

std::string material_for(ObjectClass c) {
  return c == ObjectClass::Pedestrian ? "skin_fabric" : c == ObjectClass::Cyclist ? "metal" : "car_paint";
}

double to_number(const std::string& s, const std::string& file, const std::string& where, const char* name) {
  size_t used = 0;
  double v = 0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != s.size() || s.empty())
    throw input_error(file, where, std::string(name) + ": expected a number, got \"" + s + "\"");
  if (!std::isfinite(v)) throw input_error(file, where, std::string(name) + ": must be finite, got " + s);
  return v;
}

int to_int(const std::string& s, const std::string& file, const std::string& where, const char* name) {
  const double v = to_number(s, file, where, name);
  if (v != std::floor(v) || std::abs(v) > 2e9)
    throw input_error(file, where, std::string(name) + ": expected an integer, got " + s);
  return static_cast<int>(v);
}

void check_size(double h, double w, double l, const std::string& file, const std::string& where) {
  if (h <= 0 || w <= 0 || l <= 0 || h > kMaxBoxSize || w > kMaxBoxSize || l > kMaxBoxSize)
    throw input_error(file, where, "box size h, w, l: must be positive and at most " +
                                       std::to_string(static_cast<int>(kMaxBoxSize)) + " m, got " + std::to_string(h) +
                                       ", " + std::to_string(w) + ", " + std::to_string(l));
}

void check_position(const Eigen::Vector3d& p, const std::string& file, const std::string& where) {
  if (p.cwiseAbs().maxCoeff() > kMaxBoxPosition)
    throw input_error(file, where, "position x, y, z: must lie within " +
                                       std::to_string(static_cast<int>(kMaxBoxPosition)) + " m of the camera");
}

int frame_index(const std::string& s, const std::string& file, const std::string& where) {
  const int frame = to_int(s, file, where, "frame");
  if (frame < 0 || frame > kMaxFrameIndex)
    throw input_error(file, where, "frame: must be in [0, " + std::to_string(kMaxFrameIndex) + "], got " + s);
  return frame;
}

// Calls record(fields, where) for each non-blank line of a text file ("where" = "line N"). Fields
// are split at white space when separator is 0, else at the separator with blanks trimmed.
template <typename Record>
void for_each_record(const fs::path& path, const std::string& what, char separator, Record&& record) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "(file)", "cannot open the " + what);
  std::string line;
  int line_no = 0;
  std::vector<std::string> f;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    f.clear();
    std::istringstream ss(line);
    if (separator == 0) {
      for (std::string tok; ss >> tok;) f.push_back(tok);
    } else {
      for (std::string tok; std::getline(ss, tok, separator);) {
        tok.erase(0, tok.find_first_not_of(" \t"));
        tok.erase(tok.find_last_not_of(" \t") + 1);
        f.push_back(tok);
      }
    }
    record(f, "line " + std::to_string(line_no));
  }
}

}  // namespace

std::vector<KittiTrackingObject> read_kitti_tracking_labels(const fs::path& path, const KittiBoxConverter& conv) {
  const std::string file = path.string();
  std::vector<KittiTrackingObject> out;
  for_each_record(path, "KITTI tracking label file", 0, [&](const std::vector<std::string>& f, const std::string& where) {
    if (f.size() != 17 && f.size() != 18)  // 18: a trailing score column, as some tools write
      throw input_error(file, where, "expected 17 space-separated fields (frame track_id type truncated occluded "
                                     "alpha bbox[4] h w l x y z rotation_y), got " + std::to_string(f.size()));
    const std::string& type = f[2];
    if (type == "DontCare") return;
    KittiTrackingObject o;
    o.frame = frame_index(f[0], file, where);
    const int track = to_int(f[1], file, where, "track_id");
    if (track < 0) throw input_error(file, where, "track_id: must be >= 0 (only DontCare lines carry -1), got " + f[1]);
    o.type = type;
    try {
      o.object.cls = kitti_type_to_class(type);
    } catch (const Error& e) {
      throw input_error(file, where, std::string("type: ") + e.what());
    }
    o.truncated = to_number(f[3], file, where, "truncated");
    o.occluded = to_int(f[4], file, where, "occluded");
    const double h = to_number(f[10], file, where, "h"), w = to_number(f[11], file, where, "w"),
                 l = to_number(f[12], file, where, "l");
    check_size(h, w, l, file, where);
    const Eigen::Vector3d bottom(to_number(f[13], file, where, "x"), to_number(f[14], file, where, "y"),
                                 to_number(f[15], file, where, "z"));
    check_position(bottom, file, where);
    const double ry = to_number(f[16], file, where, "rotation_y");
    const ObjectClass cls = o.object.cls;
    o.object = conv.convert(h, w, l, bottom, ry);
    o.object.cls = cls;
    o.object.id = track;
    o.object.material = material_for(cls);
    // KITTI occlusion level and truncation (the part outside the camera image, which the
    // camera-bounded labels and detector do not see) as a visible fraction for the KPI model.
    // Tracking labels give truncation as a level 0, 1, 2 (the object benchmark as a share):
    // clamped, levels 1 and 2 both read as "truncated", 1, as the visible fraction always has.
    o.object.truncation = std::clamp(o.truncated, 0.0, 1.0);
    const double occl = o.occluded == 0 ? 1.0 : o.occluded == 1 ? 0.6 : 0.2;
    o.object.visible_fraction = occl * (1.0 - o.object.truncation);
    out.push_back(std::move(o));
  });
  return out;
}

std::vector<KittiTrackingObject> read_ab3dmot_detections(const fs::path& path, const KittiBoxConverter& conv) {
  const std::string file = path.string();
  std::vector<KittiTrackingObject> out;
  for_each_record(path, "detection file", ',', [&](const std::vector<std::string>& f, const std::string& where) {
    if (f.size() != 15)
      throw input_error(file, where, "expected 15 comma-separated fields (frame, type_id, x1, y1, x2, y2, score, "
                                     "h, w, l, x, y, z, rot_y, alpha), got " + std::to_string(f.size()));
    KittiTrackingObject o;
    o.frame = frame_index(f[0], file, where);
    const int type_id = to_int(f[1], file, where, "type_id");
    if (type_id < 1 || type_id > 3)
      throw input_error(file, where, "type_id: expected 1 (Pedestrian), 2 (Car) or 3 (Cyclist), got " + f[1]);
    o.type = type_id == 1 ? "Pedestrian" : type_id == 2 ? "Car" : "Cyclist";
    const double score = to_number(f[6], file, where, "score");
    const double h = to_number(f[7], file, where, "h"), w = to_number(f[8], file, where, "w"),
                 l = to_number(f[9], file, where, "l");
    check_size(h, w, l, file, where);
    const Eigen::Vector3d bottom(to_number(f[10], file, where, "x"), to_number(f[11], file, where, "y"),
                                 to_number(f[12], file, where, "z"));
    check_position(bottom, file, where);
    const double ry = to_number(f[13], file, where, "rot_y");
    to_number(f[14], file, where, "alpha");
    const ObjectClass cls = kitti_type_to_class(o.type);
    o.object = conv.convert(h, w, l, bottom, ry);
    o.object.cls = cls;
    o.object.id = static_cast<int>(out.size());
    o.object.score = score;
    o.object.material = material_for(cls);
    out.push_back(std::move(o));
  });
  return out;
}

std::vector<std::string> read_kitti_seqmap(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "(file)", "cannot open the seqmap file");
  std::vector<std::string> names;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ss(line);
    std::string name;
    if (!(ss >> name)) continue;
    if (name.find_first_not_of("0123456789") != std::string::npos)
      throw input_error(path.string(), "line " + std::to_string(line_no), "expected a sequence number, got \"" + name + "\"");
    names.push_back(name);
  }
  return names;
}

KittiTrackingSequence read_kitti_tracking_sequence(const fs::path& root, const std::string& name,
                                                   const std::string& detector) {
  KittiTrackingSequence seq;
  seq.name = name;
  const fs::path calib = root / "calib" / (name + ".txt");
  if (!fs::exists(calib)) throw input_error(calib.string(), "(file)", "missing: KITTI tracking calib for sequence " + name);
  seq.calib = read_kitti_calib(calib);
  const KittiBoxConverter conv(seq.calib);
  const fs::path labels = root / "label_02" / (name + ".txt");
  std::vector<KittiTrackingObject> truth = read_kitti_tracking_labels(labels, conv);
  std::vector<KittiTrackingObject> dets;
  std::vector<std::pair<fs::path, std::pair<std::size_t, std::size_t>>> det_files;  // file -> range in dets
  for (const std::string& cls : sensor::kModelledClasses) {
    const fs::path p = root / "detection" / (detector + "_" + cls + "_val") / (name + ".txt");
    if (!fs::exists(p)) continue;
    auto d = read_ab3dmot_detections(p, conv);
    const std::size_t first = dets.size();
    for (auto& x : d) dets.push_back(std::move(x));
    det_files.emplace_back(p, std::make_pair(first, dets.size()));
  }
  // The sequence ends at the last labelled frame (DontCare lines included): a detection after
  // it belongs to another sequence or a broken file.
  int last = -1;
  for_each_record(labels, "KITTI tracking label file", 0, [&](const std::vector<std::string>& f, const std::string& where) {
    if (!f.empty()) last = std::max(last, frame_index(f[0], labels.string(), where));
  });
  for (const auto& o : truth) last = std::max(last, o.frame);
  for (const auto& [path, count] : det_files) {
    const auto& d = dets;
    for (std::size_t i = count.first; i < count.second; ++i)
      if (d[i].frame > last)
        throw input_error(path.string(), "frame " + std::to_string(d[i].frame),
                          "detection after the last labelled frame (" + std::to_string(last) + ") of sequence " + name);
  }
  seq.frames.resize(last + 1);
  for (int i = 0; i <= last; ++i) seq.frames[i].frame = i;
  for (auto& o : truth) seq.frames[o.frame].truth.push_back(std::move(o));
  for (auto& o : dets) {
    o.object.id = static_cast<int>(seq.frames[o.frame].detections.size());
    seq.frames[o.frame].detections.push_back(std::move(o));
  }
  return seq;
}

sensor::CalibrationSequence to_calibration_sequence(const KittiTrackingSequence& seq) {
  sensor::CalibrationSequence out;
  out.name = seq.name;
  out.frame_dt = 0.1;  // KITTI tracking: 10 Hz
  out.frames.resize(seq.frames.size());
  for (size_t f = 0; f < seq.frames.size(); ++f) {
    const KittiTrackingFrame& in = seq.frames[f];
    sensor::CalibrationFrame& fr = out.frames[f];
    for (const auto& o : in.truth) {
      if (std::find(sensor::kModelledClasses.begin(), sensor::kModelledClasses.end(), o.type) != sensor::kModelledClasses.end()) {
        fr.truth.push_back(o.object);
        fr.occlusion.push_back(o.occluded);
      } else {
        fr.others.push_back(o.object);
      }
    }
    for (const auto& d : in.detections) fr.detections.push_back(d.object);
  }
  return out;
}

}  // namespace lidarsim::data
