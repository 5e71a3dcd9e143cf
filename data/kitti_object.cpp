#include "data/kitti_object.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
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
  if (out.size() > kManyKittiObjects)
    std::fprintf(stderr, "warning: %s: %zu objects, more than any real scene (KITTI frames list fewer than 100; warned above %zu)\n",
                 path.string().c_str(), out.size(), kManyKittiObjects);
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

namespace {

// Boxes found by the bird's-eye cells (rectified camera x, z) their footprints touch: a sorted
// list of (cell, box) pairs, box indices ascending within a cell. A box's axis-aligned footprint,
// widened by kFootprintMargin against rounding, holds every point contains_rect accepts, so the
// boxes listed for a point's cell are a superset of the boxes that contain it, in file order.
class BoxGrid {
 public:
  BoxGrid(const std::vector<KittiObjectLabel>& labels, const std::vector<int>& classes);
  // Indices of the boxes whose footprint touches the cell of (x, z), ascending.
  std::pair<const std::uint32_t*, const std::uint32_t*> candidates(double x, double z) const;
  // False only when (x, z) lies outside box k's footprint, where contains_rect is false too.
  bool may_contain(std::uint32_t k, double x, double z) const {
    const Footprint& f = footprint_[k];
    return x >= f.x0 && x <= f.x1 && z >= f.z0 && z <= f.z1;
  }

 private:
  static constexpr double kFootprintMargin = 1e-3;  // m; rounding in contains_rect is ~1e-12 m
  // Per box the footprint rectangle [x0, x1] x [z0, z1].
  struct Footprint { double x0, x1, z0, z1; std::uint32_t box; };
  std::int64_t cells_of(const Footprint& f, double cell) const;
  // |ix|, |iz| < 2^31 (cell_index), so the pair packs into one 64-bit key without collisions.
  static std::int64_t key(std::int64_t ix, std::int64_t iz) {
    return static_cast<std::int64_t>((static_cast<std::uint64_t>(ix) << 32) | (static_cast<std::uint64_t>(iz) & 0xffffffffULL));
  }
  bool cell_index(double v, std::int64_t& i) const;

  double cell_ = 1;
  // Labels outside the plausibility limits (possible only when not read by
  // read_kitti_object_labels): every box is a candidate everywhere, in file order.
  std::vector<std::uint32_t> every_box_;
  std::vector<Footprint> footprint_;  // by label index (DontCare: empty)
  std::vector<std::int64_t> keys_;      // sorted; keys_[i] is the cell of boxes_[i]
  std::vector<std::uint32_t> boxes_;
};

bool BoxGrid::cell_index(double v, std::int64_t& i) const {
  const double f = std::floor(v / cell_);
  // No box reaches this far (positions are at most kMaxBoxPosition, sizes kMaxBoxSize).
  if (!(std::abs(f) < 1e9)) return false;
  i = static_cast<std::int64_t>(f);
  return true;
}

std::int64_t BoxGrid::cells_of(const Footprint& f, double cell) const {
  const auto n = [cell](double a, double b) { return static_cast<std::int64_t>(std::floor(b / cell) - std::floor(a / cell)) + 1; };
  return n(f.x0, f.x1) * n(f.z0, f.z1);
}

BoxGrid::BoxGrid(const std::vector<KittiObjectLabel>& labels, const std::vector<int>& classes) {
  std::vector<Footprint> fp;
  std::vector<double> extents;
  for (std::size_t k = 0; k < labels.size(); ++k) {
    if (classes[k] < 0) continue;
    const auto& o = labels[k];
    const double c = std::abs(std::cos(o.rotation_y)), s = std::abs(std::sin(o.rotation_y));
    const double hx = c * o.l / 2 + s * o.w / 2 + kFootprintMargin;
    const double hz = s * o.l / 2 + c * o.w / 2 + kFootprintMargin;
    fp.push_back({o.location.x() - hx, o.location.x() + hx, o.location.z() - hz, o.location.z() + hz, static_cast<std::uint32_t>(k)});
    extents.push_back(2 * std::max(hx, hz));
  }
  if (fp.empty()) return;
  footprint_.assign(labels.size(), Footprint{1, 0, 1, 0, 0});
  for (const auto& f : fp) footprint_[f.box] = f;
  const double reach = 2 * (kMaxBoxPosition + kMaxBoxSize);
  for (const auto& f : fp)
    if (!(std::abs(f.x0) < reach && std::abs(f.x1) < reach && std::abs(f.z0) < reach && std::abs(f.z1) < reach)) {
      for (const auto& g : fp) every_box_.push_back(g.box);
      for (auto& g : footprint_) g = {-HUGE_VAL, HUGE_VAL, -HUGE_VAL, HUGE_VAL, g.box};
      return;
    }
  // Cells half a typical box: a box touches about nine cells, a point's cell lists the boxes near
  // it. Coarser cells if oversized boxes would list too many (memory stays O(boxes)).
  std::nth_element(extents.begin(), extents.begin() + extents.size() / 2, extents.end());
  cell_ = std::max(extents[extents.size() / 2] / 2, 0.5);
  const std::int64_t budget = 64 * static_cast<std::int64_t>(fp.size()) + (1 << 20);
  for (;;) {
    std::int64_t total = 0;
    for (const auto& f : fp) total += cells_of(f, cell_);
    if (total <= budget) break;
    cell_ *= 2;
  }
  std::vector<std::pair<std::int64_t, std::uint32_t>> entries;
  for (const auto& f : fp) {
    std::int64_t ix0 = 0, ix1 = 0, iz0 = 0, iz1 = 0;
    cell_index(f.x0, ix0), cell_index(f.x1, ix1), cell_index(f.z0, iz0), cell_index(f.z1, iz1);
    for (std::int64_t ix = ix0; ix <= ix1; ++ix)
      for (std::int64_t iz = iz0; iz <= iz1; ++iz) entries.emplace_back(key(ix, iz), f.box);
  }
  std::sort(entries.begin(), entries.end());  // by cell, then box index: file order per cell
  keys_.reserve(entries.size());
  boxes_.reserve(entries.size());
  for (const auto& [k, b] : entries) keys_.push_back(k), boxes_.push_back(b);
}

std::pair<const std::uint32_t*, const std::uint32_t*> BoxGrid::candidates(double x, double z) const {
  if (!every_box_.empty()) return {every_box_.data(), every_box_.data() + every_box_.size()};
  std::int64_t ix = 0, iz = 0;
  if (keys_.empty() || !cell_index(x, ix) || !cell_index(z, iz)) return {nullptr, nullptr};
  const auto [lo, hi] = std::equal_range(keys_.begin(), keys_.end(), key(ix, iz));
  const std::uint32_t* base = boxes_.data();
  return {base + (lo - keys_.begin()), base + (hi - keys_.begin())};
}

}  // namespace

std::vector<std::size_t> label_points_from_boxes(std::vector<pgm::Point>& points, const KittiCalib& calib,
                                                 const std::vector<KittiObjectLabel>& labels) {
  std::vector<std::size_t> points_in_box(labels.size(), 0);
  std::vector<int> classes;
  for (const auto& o : labels) classes.push_back(o.type == "DontCare" ? -1 : pgm::class_from_object_type(o.type));
  const BoxGrid grid(labels, classes);
  for (auto& p : points) {
    p.class_id = pgm::cls::unlabeled;
    p.material_id = pgm::material::unknown;
    const Eigen::Vector3d rect = calib.velo_to_rect({p.x, p.y, p.z});
    const auto [first, last] = grid.candidates(rect.x(), rect.z());
    for (const std::uint32_t* k = first; k != last; ++k) {
      if (!grid.may_contain(*k, rect.x(), rect.z()) || !labels[*k].contains_rect(rect)) continue;
      p.class_id = classes[*k];
      p.material_id = pgm::default_material(classes[*k]);
      ++points_in_box[*k];
      break;
    }
  }
  return points_in_box;
}

KittiObjectScan read_kitti_object_scan(const KittiObjectFrame& frame) {
  KittiObjectScan scan;
  scan.points = read_velodyne_bin(frame.bin);
  const KittiCalib calib = read_kitti_calib(frame.calib);
  scan.labels = read_kitti_object_labels(frame.label);
  scan.sources = {frame.bin, frame.label, frame.calib};
  scan.points_in_box = label_points_from_boxes(scan.points, calib, scan.labels);
  return scan;
}

}  // namespace lidarsim::data
