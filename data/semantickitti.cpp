#include "data/semantickitti.h"

#include <algorithm>

#include "common/error.h"
#include "data/velodyne.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

namespace {

void add_sequence(const fs::path& seq_dir, const std::string& seq, std::vector<ScanFiles>& out) {
  std::vector<ScanFiles> found;
  for (const auto& e : fs::directory_iterator(seq_dir / "velodyne")) {
    // Anything named *.bin but a folder is listed, dangling links included: a scan that cannot
    // be read is then an error (or, when asked, skipped and counted), never silently missing.
    std::error_code ec;
    if (e.path().extension() != ".bin" || e.is_directory(ec)) continue;
    ScanFiles f;
    f.sequence = seq;
    f.id = e.path().stem().string();
    f.bin = e.path();
    const fs::path in_labels = seq_dir / "labels" / (f.id + ".label");
    const fs::path beside = seq_dir / "velodyne" / (f.id + ".label");
    if (fs::is_regular_file(in_labels)) f.label = in_labels;
    else if (fs::is_regular_file(beside)) f.label = beside;
    found.push_back(f);
  }
  std::sort(found.begin(), found.end(), [](const ScanFiles& a, const ScanFiles& b) { return a.id < b.id; });
  out.insert(out.end(), found.begin(), found.end());
}

}  // namespace

std::vector<ScanFiles> list_semantickitti(const fs::path& dir_in, const std::vector<std::string>& sequences) {
  fs::path dir = dir_in;
  if (dir.filename().empty()) dir = dir.parent_path();  // "folder/" -> "folder"
  if (!fs::is_directory(dir)) throw input_error(dir.string(), "folder", "not found");
  auto wanted = [&](const std::string& s) {
    return sequences.empty() || std::find(sequences.begin(), sequences.end(), s) != sequences.end();
  };
  std::vector<ScanFiles> out;
  auto scan_sequences = [&](const fs::path& root) {
    std::vector<fs::path> seqs;
    for (const auto& e : fs::directory_iterator(root))
      if (e.is_directory() && fs::is_directory(e.path() / "velodyne")) seqs.push_back(e.path());
    std::sort(seqs.begin(), seqs.end());
    for (const auto& s : seqs)
      if (wanted(s.filename().string())) add_sequence(s, s.filename().string(), out);
    return !seqs.empty();
  };
  if (fs::is_directory(dir / "velodyne")) {
    add_sequence(dir, dir.filename().string(), out);
  } else if (!(fs::is_directory(dir / "sequences") && scan_sequences(dir / "sequences")) && !scan_sequences(dir)) {
    throw input_error(dir.string(), "layout",
                      "no velodyne/ folder found (expected DIR/sequences/NN/velodyne, DIR/NN/velodyne or DIR/velodyne)");
  }
  return out;
}

LabelledScan read_semantickitti_scan(const ScanFiles& files) {
  LabelledScan scan;
  scan.points = read_velodyne_bin(files.bin);
  scan.sources.push_back(files.bin);
  if (files.label) {
    const auto labels = read_label_file(*files.label, scan.points.size());
    scan.sources.push_back(*files.label);
    for (std::size_t i = 0; i < labels.size(); ++i) {
      const std::uint32_t semantic = labels[i] & 0xFFFFu;
      if (!pgm::is_known_semantickitti_label(semantic)) ++scan.unknown_labels;
      scan.points[i].class_id = pgm::class_from_semantickitti(semantic);
      scan.points[i].material_id = pgm::default_material(scan.points[i].class_id);
    }
  }
  return scan;
}

}  // namespace lidarsim::data
