#include "data/semantickitti_mos.h"

#include "common/error.h"
#include "data/velodyne.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

std::vector<ScanFiles> list_semantickitti_mos(const fs::path& dir, const std::vector<std::string>& sequences) {
  std::vector<ScanFiles> scans = list_semantickitti(dir, sequences);
  for (auto& s : scans) {
    // list_semantickitti paired the scan with a semantic label file; MOS labels live elsewhere.
    const fs::path seq_dir = s.bin.parent_path().parent_path();
    const fs::path folder = fs::is_directory(seq_dir / "labels_mos") ? seq_dir / "labels_mos" : seq_dir / "labels";
    const fs::path label = folder / (s.id + ".label");
    s.label.reset();
    if (fs::is_regular_file(label)) s.label = label;
  }
  return scans;
}

std::vector<Motion> read_mos_labels(const fs::path& path, std::size_t points) {
  const std::vector<std::uint32_t> raw = read_label_file(path, points);
  std::vector<Motion> motion(raw.size());
  for (std::size_t i = 0; i < raw.size(); ++i) {
    const std::uint32_t v = raw[i] & 0xFFFFu;
    if (v == kMosStatic) motion[i] = Motion::Static;
    else if (v == kMosMovable) motion[i] = Motion::Movable;
    else if (v == kMosMoving) motion[i] = Motion::Moving;
    else
      throw input_error(path.string(), "point " + std::to_string(i) + " label",
                        "lower 16 bits are " + std::to_string(v) +
                            ", not a moving-object label (8 static, 250 movable, 251 moving); semantic SemanticKITTI "
                            "labels import with --semantickitti");
  }
  return motion;
}

MosScan read_semantickitti_mos_scan(const ScanFiles& files) {
  if (!files.label) throw input_error(files.bin.string(), "label", "no moving-object label file for this scan");
  MosScan scan;
  scan.points = read_velodyne_bin(files.bin);
  const std::vector<Motion> motion = read_mos_labels(*files.label, scan.points.size());
  scan.sources = {files.bin, *files.label};
  scan.motion.resize(motion.size());
  for (std::size_t i = 0; i < motion.size(); ++i) {
    scan.points[i].class_id = pgm::cls::unlabeled;
    scan.points[i].material_id = pgm::default_material(pgm::cls::unlabeled);
    scan.motion[i] = static_cast<float>(motion[i]);
    ++scan.counts[static_cast<std::size_t>(motion[i])];
  }
  return scan;
}

}  // namespace lidarsim::data
