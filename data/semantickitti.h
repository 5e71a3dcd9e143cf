#pragma once
// SemanticKITTI, read as it is. Accepted folder layouts (the first that matches wins):
//   DIR/sequences/NN/{velodyne,labels}/   the dataset root (every sequence NN)
//   DIR/NN/{velodyne,labels}/             the sequences folder itself
//   DIR/{velodyne,labels}/                one sequence folder
// Each velodyne/XXXXXX.bin pairs with labels/XXXXXX.label (or, as some copies ship them, a
// .label beside the .bin). Classes: the lower 16 bits of the label through
// pgm::class_from_semantickitti; material = pgm::default_material(class).
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "pgm/projection.h"

namespace lidarsim::data {

struct ScanFiles {
  std::string sequence;  // "00"
  std::string id;        // "000000"
  std::filesystem::path bin;
  std::optional<std::filesystem::path> label;
};

// All scans under `dir`, sorted by sequence and id; `sequences` (e.g. {"00"}) filters when not
// empty. Throws lidarsim::Error naming `dir` when no velodyne/ folder is found.
std::vector<ScanFiles> list_semantickitti(const std::filesystem::path& dir,
                                          const std::vector<std::string>& sequences = {});

struct LabelledScan {
  std::vector<pgm::Point> points;  // in file order (= firing order for KITTI)
  std::vector<std::filesystem::path> sources;
  std::size_t unknown_labels = 0;  // labels outside the SemanticKITTI definition (mapped to unlabeled)
};

// Reads the .bin and, when present, the .label (class + material per point).
LabelledScan read_semantickitti_scan(const ScanFiles& files);

}  // namespace lidarsim::data
