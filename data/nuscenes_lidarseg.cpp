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
  for (std::size_t i = 0; i < all.size(); ++i) {
    if (labels[i] == kNuscenesEgoClass) {
      ++scan.ego;
      continue;
    }
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
  layout.validate("nuscenes-lidarseg: beam layout");
  auto files = list_nuscenes_lidarseg(dir);
  const std::size_t first = std::min<std::size_t>(std::max(options.first, 0), files.size());
  std::size_t last = files.size();
  if (options.max_frames > 0) last = std::min(last, first + static_cast<std::size_t>(options.max_frames));
  files = std::vector<NuscenesLidarsegFiles>(files.begin() + first, files.begin() + last);
  if (files.empty()) throw input_error(dir.string(), "scans", "none left after --first/--max-frames");

  pgm::ProjectOptions po;
  po.row_mode = pgm::RowMode::Ring;  // the recorded ring; read_nuscenes_pcd_bin flips it so row 0 is the top beam
  po.extra_channels = options.extra_channels;
  po.min_range = options.min_range;
  const std::string scene = fs::weakly_canonical(dir).filename().string();
  Dataset d;
  d.layout = layout;
  d.channels = dataset_channels(options);
  d.source_format = to_string(SourceFormat::Nuscenes);
  std::size_t ego = 0;
  std::map<std::string, std::size_t> unmapped;
  for (const auto& f : files) {
    NuscenesLidarsegScan scan = read_nuscenes_lidarseg_scan(f, classes);
    ego += scan.ego;
    for (const auto& [name, n] : scan.unmapped) unmapped[name] += n;
    auto projected = pgm::project(scan.points, layout, po, f.pcd.string());
    d.append(projected.pgm, "nuscenes/" + scene + "/" + f.id, pgm::to_string(projected.row_mode), {"nuscenes", scene, f.id});
    for (const auto& s : scan.sources) d.sources.push_back(s.string());
  }
  if (options.note) {
    std::string text = dir.string() + ": " + std::to_string(files.size()) + " labelled sweeps; dropped " +
                       std::to_string(ego) + " vehicle.ego points";
    for (const auto& [name, n] : unmapped) text += "; " + name + " " + std::to_string(n) + " imported as unlabeled";
    options.note(text);
  }
  return d;
}

}  // namespace lidarsim::data
