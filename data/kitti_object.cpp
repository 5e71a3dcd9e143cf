#include "data/kitti_object.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include "common/error.h"
#include "data/plausibility.h"
#include "data/velodyne.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

Eigen::Vector3d KittiCalib::velo_to_rect(const Eigen::Vector3d& p) const {
  return R0_rect * (Tr_velo_to_cam.leftCols<3>() * p + Tr_velo_to_cam.col(3));
}

Eigen::Vector3d KittiCalib::rect_to_velo(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d cam = R0_rect.inverse() * p;
  return Tr_velo_to_cam.leftCols<3>().inverse() * (cam - Tr_velo_to_cam.col(3));
}

KittiCalib read_kitti_calib(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "file", "cannot be opened");
  std::map<std::string, std::vector<double>> entries;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string key = line.substr(0, colon);
    key.erase(0, key.find_first_not_of(" \t"));
    std::istringstream values(line.substr(colon + 1));
    std::vector<double> v;
    std::string tok;
    while (values >> tok) {
      double d;
      if (!parse_double(tok, d))
        throw input_error(path.string(), key + " (line " + std::to_string(line_no) + ")", "'" + tok + "' is not a number");
      if (!std::isfinite(d)) throw input_error(path.string(), key, "not a finite number");
      v.push_back(d);
    }
    entries[key] = v;
  }
  auto get = [&](std::initializer_list<const char*> keys, std::size_t count, bool required) -> const std::vector<double>* {
    for (const char* k : keys) {
      auto it = entries.find(k);
      if (it == entries.end()) continue;
      if (it->second.size() != count)
        throw input_error(path.string(), k, "expected " + std::to_string(count) + " numbers, got " +
                                                std::to_string(it->second.size()));
      return &it->second;
    }
    if (required) throw input_error(path.string(), *keys.begin(), "missing");
    return nullptr;
  };
  KittiCalib calib;
  const auto* r0 = get({"R0_rect", "R0"}, 9, true);
  const auto* tr = get({"Tr_velo_to_cam", "Tr_velo_cam"}, 12, true);
  for (int i = 0; i < 9; ++i) calib.R0_rect(i / 3, i % 3) = (*r0)[i];
  for (int i = 0; i < 12; ++i) calib.Tr_velo_to_cam(i / 4, i % 4) = (*tr)[i];
  // A singular rotation part cannot map the Velodyne into the camera (and back).
  if (std::abs(calib.R0_rect.determinant()) < kMinSingularDeterminant)
    throw input_error(path.string(), "R0_rect", "singular matrix (determinant " + std::to_string(calib.R0_rect.determinant()) + ")");
  const double det_tr = calib.Tr_velo_to_cam.leftCols<3>().determinant();
  if (std::abs(det_tr) < kMinSingularDeterminant)
    throw input_error(path.string(), "Tr_velo_to_cam", "singular rotation part (determinant " + std::to_string(det_tr) + ")");
  if (const auto* p2 = get({"P2"}, 12, false))
    for (int i = 0; i < 12; ++i) calib.P2(i / 4, i % 4) = (*p2)[i];
  return calib;
}

bool KittiObjectLabel::contains_rect(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d d = p - location;
  // Box axes: length along the object's x, which is the camera x rotated by rotation_y about y.
  const double c = std::cos(rotation_y), s = std::sin(rotation_y);
  const double along = c * d.x() - s * d.z();  // object x (length)
  const double across = s * d.x() + c * d.z();  // object z (width)
  return std::abs(along) <= l / 2 && std::abs(across) <= w / 2 && d.y() <= 0 && d.y() >= -h;
}

std::vector<KittiObjectLabel> read_kitti_object_labels(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "file", "cannot be opened");
  std::vector<KittiObjectLabel> out;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ss(line);
    std::vector<std::string> tok;
    for (std::string t; ss >> t;) tok.push_back(t);
    if (tok.empty()) continue;
    const std::string where = "line " + std::to_string(line_no);
    if (tok.size() != 15 && tok.size() != 16)
      throw input_error(path.string(), where, "expected 15 fields (type ... rotation_y), got " + std::to_string(tok.size()));
    double v[15];
    for (int i = 1; i < 15; ++i) {
      if (!parse_double(tok[i], v[i]))
        throw input_error(path.string(), where + " field " + std::to_string(i + 1), "'" + tok[i] + "' is not a number");
      if (!std::isfinite(v[i])) throw input_error(path.string(), where + " field " + std::to_string(i + 1), "not finite");
    }
    KittiObjectLabel o;
    o.type = tok[0];
    o.truncated = v[1];
    o.occluded = v[2];
    o.alpha = v[3];
    for (int k = 0; k < 4; ++k) o.bbox[k] = v[4 + k];
    o.h = v[8];
    o.w = v[9];
    o.l = v[10];
    o.location = {v[11], v[12], v[13]};
    o.rotation_y = v[14];
    if (o.type != "DontCare") {
      try {
        pgm::class_from_object_type(o.type);
      } catch (const Error& e) {
        throw input_error(path.string(), where + " type", e.what());
      }
      if (!(o.h > 0 && o.w > 0 && o.l > 0))
        throw input_error(path.string(), where + " dimensions", "h, w, l must be positive");
      if (o.h > kMaxBoxSize || o.w > kMaxBoxSize || o.l > kMaxBoxSize)
        throw input_error(path.string(), where + " dimensions",
                          "h, w, l must be at most " + std::to_string(static_cast<int>(kMaxBoxSize)) + " m");
      if (o.location.cwiseAbs().maxCoeff() > kMaxBoxPosition)
        throw input_error(path.string(), where + " location",
                          "must lie within " + std::to_string(static_cast<int>(kMaxBoxPosition)) + " m of the camera");
    }
    out.push_back(o);
  }
  return out;
}

std::vector<KittiObjectFrame> list_kitti_object(const fs::path& dir_in) {
  fs::path dir = dir_in;
  if (!fs::is_directory(dir / "velodyne") && fs::is_directory(dir / "training" / "velodyne")) dir = dir / "training";
  if (!fs::is_directory(dir / "velodyne"))
    throw input_error(dir_in.string(), "layout", "no velodyne/ folder (expected DIR/velodyne, label_2, calib)");
  std::vector<KittiObjectFrame> frames;
  for (const auto& e : fs::directory_iterator(dir / "velodyne")) {
    std::error_code ec;  // dangling links are listed too: reading them is then an error
    if (e.path().extension() != ".bin" || e.is_directory(ec)) continue;
    KittiObjectFrame f;
    f.id = e.path().stem().string();
    f.bin = e.path();
    f.label = dir / "label_2" / (f.id + ".txt");
    f.calib = dir / "calib" / (f.id + ".txt");
    if (!fs::is_regular_file(f.label)) throw input_error(f.label.string(), "file", "missing (label_2 of " + f.id + ")");
    if (!fs::is_regular_file(f.calib)) throw input_error(f.calib.string(), "file", "missing (calib of " + f.id + ")");
    frames.push_back(f);
  }
  std::sort(frames.begin(), frames.end(), [](const auto& a, const auto& b) { return a.id < b.id; });
  return frames;
}

KittiObjectScan read_kitti_object_scan(const KittiObjectFrame& frame) {
  KittiObjectScan scan;
  scan.points = read_velodyne_bin(frame.bin);
  const KittiCalib calib = read_kitti_calib(frame.calib);
  scan.labels = read_kitti_object_labels(frame.label);
  scan.sources = {frame.bin, frame.label, frame.calib};
  scan.points_in_box.assign(scan.labels.size(), 0);
  std::vector<int> classes;
  for (const auto& o : scan.labels) classes.push_back(o.type == "DontCare" ? -1 : pgm::class_from_object_type(o.type));
  for (auto& p : scan.points) {
    p.class_id = pgm::cls::unlabeled;
    p.material_id = pgm::material::unknown;
    const Eigen::Vector3d rect = calib.velo_to_rect({p.x, p.y, p.z});
    for (std::size_t k = 0; k < scan.labels.size(); ++k) {
      if (classes[k] < 0 || !scan.labels[k].contains_rect(rect)) continue;
      p.class_id = classes[k];
      p.material_id = pgm::default_material(classes[k]);
      ++scan.points_in_box[k];
      break;
    }
  }
  return scan;
}

}  // namespace lidarsim::data
