#include "data/rellis3d.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "common/error.h"
#include "data/binary_file.h"
#include "data/ply_reader.h"
#include "data/velodyne.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace fs = std::filesystem;
namespace {

std::optional<fs::path> find_ply(const fs::path& folder, const std::string& id) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return std::nullopt;
  const std::string prefix = "frame" + id + "-";
  for (const auto& e : fs::directory_iterator(folder)) {
    const std::string name = e.path().filename().string();
    if (name.rfind(prefix, 0) == 0 && e.path().extension() == ".ply") return e.path();
  }
  return std::nullopt;
}

// The .bin files of one folder with their label and PLY (beside them or in the dataset's
// sibling folders).
void add_folder(const fs::path& bins, const std::string& sequence, std::vector<Rellis3dFiles>& out) {
  const fs::path root = bins.parent_path();
  for (const auto& e : fs::directory_iterator(bins)) {
    if (!e.is_regular_file() || e.path().extension() != ".bin") continue;
    Rellis3dFiles f;
    f.sequence = sequence;
    f.id = e.path().stem().string();
    f.bin = e.path();
    for (const fs::path& label : {bins / (f.id + ".label"), root / "os1_cloud_node_semantickitti_label_id" / (f.id + ".label")})
      if (fs::is_regular_file(label)) {
        f.label = label;
        break;
      }
    f.ply = find_ply(bins, f.id);
    if (!f.ply) f.ply = find_ply(root / "os1_cloud_node_color_ply", f.id);
    out.push_back(f);
  }
}

}  // namespace

std::vector<Rellis3dFiles> list_rellis3d(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw input_error(dir.string(), "folder", "not found");
  std::vector<Rellis3dFiles> out;
  const char* kBins = "os1_cloud_node_kitti_bin";
  if (fs::is_directory(dir / kBins)) {
    add_folder(dir / kBins, dir.filename().string(), out);
  } else if (dir.filename() == kBins) {
    add_folder(dir, dir.parent_path().filename().string(), out);
  } else {
    bool sequences = false;
    for (const auto& e : fs::directory_iterator(dir))
      if (e.is_directory() && fs::is_directory(e.path() / kBins)) {
        add_folder(e.path() / kBins, e.path().filename().string(), out);
        sequences = true;
      }
    if (!sequences) add_folder(dir, dir.filename().string(), out);
  }
  if (out.empty()) throw input_error(dir.string(), "scans", "no .bin scans found (flat, SEQ/" + std::string(kBins) + "/ or " + kBins + "/)");
  std::sort(out.begin(), out.end(), [](const Rellis3dFiles& a, const Rellis3dFiles& b) {
    return a.sequence != b.sequence ? a.sequence < b.sequence : a.id < b.id;
  });
  return out;
}

Rellis3dScan read_rellis3d_scan(const Rellis3dFiles& files, const ClassTable& classes) {
  Rellis3dScan scan;
  const std::vector<pgm::Point> cells = read_velodyne_bin(files.bin);  // same x, y, z, intensity float32 layout
  scan.sources.push_back(files.bin);
  scan.cells = cells.size();
  if (cells.size() % kRellisRings != 0)
    throw input_error(files.bin.string(), "size", std::to_string(cells.size()) + " points is not a whole number of " +
                                                      std::to_string(kRellisRings) + "-ring columns (organized OS1-64 scan expected)");
  std::vector<std::uint32_t> labels;
  if (files.label) {
    labels = read_label_file(*files.label, cells.size());
    scan.sources.push_back(*files.label);
  }
  std::vector<double> reflectivity;
  if (files.ply) {
    const PlyCloud ply = read_ply(*files.ply);
    if (ply.size() != cells.size())
      throw input_error(files.ply->string(), "vertex count", std::to_string(ply.size()) + " vertices but " +
                                                                 files.bin.string() + " has " + std::to_string(cells.size()));
    const auto &x = ply.at("x"), &y = ply.at("y"), &z = ply.at("z");
    for (std::size_t k = 0; k < cells.size(); ++k)
      if (std::abs(x[k] - cells[k].x) > 1e-4 || std::abs(y[k] - cells[k].y) > 1e-4 || std::abs(z[k] - cells[k].z) > 1e-4)
        throw input_error(files.ply->string(), "vertex " + std::to_string(k),
                          "x, y, z differ from " + files.bin.string() + " (not the same scan)");
    const auto& ring = ply.at("ring");
    for (std::size_t k = 0; k < cells.size(); ++k)
      if (static_cast<int>(ring[k]) != static_cast<int>(k % kRellisRings))
        throw input_error(files.ply->string(), "vertex " + std::to_string(k) + " ring",
                          "is " + std::to_string(static_cast<int>(ring[k])) + ", the organized order says " +
                              std::to_string(k % kRellisRings));
    reflectivity = ply.at("reflectivity");
    scan.sources.push_back(*files.ply);
    scan.reflectivity = true;
  }
  for (std::size_t k = 0; k < cells.size(); ++k) {
    const pgm::Point& c = cells[k];
    const int rellis = labels.empty() ? 0 : static_cast<int>(labels[k] & 0xFFFFu);
    if (c.x == 0.f && c.y == 0.f && c.z == 0.f) continue;  // no return
    pgm::Point p = c;
    p.ring = static_cast<int>(k % kRellisRings);
    if (!reflectivity.empty()) p.intensity = static_cast<float>(std::min(reflectivity[k] / kRellisReflectivityScale, 1.0));
    const int ours = classes.map(rellis);
    if (ours < 0) ++scan.unmapped[classes.name_of(rellis)];
    p.class_id = ours < 0 ? pgm::cls::unlabeled : ours;
    p.material_id = pgm::default_material(p.class_id);
    scan.points.push_back(p);
  }
  return scan;
}

}  // namespace lidarsim::data
