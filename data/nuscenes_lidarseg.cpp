#include "data/nuscenes_lidarseg.h"

#include <algorithm>

#include "common/error.h"
#include "data/binary_file.h"
#include "data/nuscenes.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

std::vector<std::uint8_t> read_nuscenes_lidarseg_labels(const fs::path& path, std::size_t points) {
  const std::vector<char> bytes = read_binary_file(path);
  if (bytes.size() != points)
    throw input_error(path.string(), "size",
                      std::to_string(bytes.size()) + " labels (one uint8 per point) for a scan of " +
                          std::to_string(points) + " points: the label file is " +
                          (bytes.size() < points ? "truncated" : "longer than its scan") + " or belongs to another scan");
  std::vector<std::uint8_t> labels(bytes.size());
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    labels[i] = static_cast<std::uint8_t>(bytes[i]);
    if (labels[i] >= kNuscenesLidarsegClasses)
      throw input_error(path.string(), "point " + std::to_string(i) + " label",
                        "class " + std::to_string(labels[i]) + " is outside the nuScenes-lidarseg taxonomy (0-31)");
  }
  return labels;
}

std::vector<NuscenesLidarsegFiles> list_nuscenes_lidarseg(const fs::path& dir) {
  const fs::path velodyne = dir / "velodyne", labels = dir / "labels";
  std::error_code ec;
  if (!fs::is_directory(velodyne, ec))
    throw input_error(dir.string(), "velodyne", "folder not found (expected velodyne/NNNNNN.pcd.bin with labels/NNNNNN.lidarseg.bin)");
  std::vector<NuscenesLidarsegFiles> out;
  for (const auto& e : fs::directory_iterator(velodyne)) {
    const std::string name = e.path().filename().string();
    const std::string ext = ".pcd.bin";
    if (!e.is_regular_file() || name.size() <= ext.size() || name.compare(name.size() - ext.size(), ext.size(), ext) != 0)
      continue;
    const std::string id = name.substr(0, name.size() - ext.size());
    const fs::path label = labels / (id + ".lidarseg.bin");
    if (!fs::is_regular_file(label, ec))
      throw input_error(e.path().string(), "labels", "no label file " + label.string() + " beside it");
    out.push_back({id, e.path(), label});
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.id < b.id; });
  if (out.empty()) throw input_error(velodyne.string(), "scans", "no *.pcd.bin files found");
  return out;
}

NuscenesLidarsegScan read_nuscenes_lidarseg_scan(const NuscenesLidarsegFiles& files, const ClassTable& classes) {
  NuscenesLidarsegScan scan;
  std::vector<pgm::Point> all = read_nuscenes_pcd_bin(files.pcd);
  const std::vector<std::uint8_t> labels = read_nuscenes_lidarseg_labels(files.labels, all.size());
  scan.read = all.size();
  scan.points.reserve(all.size());
  scan.file_index.reserve(all.size());
  for (std::size_t i = 0; i < all.size(); ++i) {
    if (labels[i] == kNuscenesEgoClass) {
      ++scan.ego;
      continue;
    }
    scan.file_index.push_back(static_cast<std::int64_t>(i));
    pgm::Point p = all[i];
    const int ours = classes.map(labels[i]);
    if (ours < 0) ++scan.unmapped[classes.name_of(labels[i])];
    p.class_id = ours < 0 ? pgm::cls::unlabeled : ours;
    p.material_id = pgm::default_material(p.class_id);
    scan.points.push_back(p);
  }
  scan.sources = {files.pcd, files.labels};
  return scan;
}

Dataset import_nuscenes_lidarseg(const fs::path& dir, const pgm::BeamLayout& layout, const ClassTable& classes,
                                 const ImportOptions& options) {
  ImportOptions o = options;
  o.layout = layout;
  o.classes = std::make_shared<const ClassTable>(classes);
  ImportSummary summary;
  Dataset d = import_dataset(SourceFormat::NuscenesLidarseg, dir, o, &summary);
  if (options.note) {
    std::string text = dir.string() + ": " + std::to_string(d.size()) + " labelled sweeps; dropped " +
                       std::to_string(summary.dropped_points) + " vehicle.ego points";
    for (const auto& [name, n] : summary.unmapped) text += "; " + name + " " + std::to_string(n) + " imported as unlabeled";
    options.note(text);
  }
  return d;
}

}  // namespace lidarsim::data
