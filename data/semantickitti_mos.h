#pragma once
// SemanticKITTI-format label files that hold moving-object segmentation (MOS) labels only, as
// moving-object-segmentation tools (LiDAR-MOS, MF-MOS) write them: one uint32 per point of the
// scan, lower 16 bits 8 (static), 250 (movable, not moving: a parked car) or 251 (moving), upper
// 16 bits an instance id. They say nothing about the semantic class, so the scans import with
// class unlabeled (pgm::cls::unlabeled, the class of "no label") and material unknown, and the
// motion goes to its own per-point channel, "motion": 0 static, 1 movable, 2 moving.
//
// Never guessed from the values: lidar-data import reads a folder this way only when asked
// (--semantickitti-mos). Folder layouts as for SemanticKITTI (data/semantickitti.h); each
// velodyne/NNNNNN.bin pairs with labels_mos/NNNNNN.label, or labels/NNNNNN.label when there is
// no labels_mos/ folder beside velodyne/ (the layout the MOS tools write).
#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "data/semantickitti.h"
#include "pgm/projection.h"

namespace lidarsim::data {

inline constexpr std::uint32_t kMosStatic = 8, kMosMovable = 250, kMosMoving = 251;
// Values of the "motion" channel.
enum class Motion : int { Static = 0, Movable = 1, Moving = 2 };
inline const std::array<std::string, 3> kMotionNames = {"static", "movable", "moving"};
inline const std::string kMotionChannel = "motion";

// Every scan under `dir` with its MOS label file when there is one (ScanFiles::label), sorted by
// sequence and id; `sequences` filters as for list_semantickitti.
std::vector<ScanFiles> list_semantickitti_mos(const std::filesystem::path& dir,
                                              const std::vector<std::string>& sequences = {});

// One Motion per point. Throws naming the file when it does not hold exactly `points` labels,
// and the file and point index for a label whose lower 16 bits are not 8, 250 or 251.
std::vector<Motion> read_mos_labels(const std::filesystem::path& path, std::size_t points);

struct MosScan {
  std::vector<pgm::Point> points;  // in file order; class unlabeled, material unknown
  std::vector<float> motion;       // per point: the Motion value
  std::vector<std::filesystem::path> sources;
  std::array<std::size_t, 3> counts{};  // points per Motion value
};

// The scan and its labels (files.label must be set).
MosScan read_semantickitti_mos_scan(const ScanFiles& files);

}  // namespace lidarsim::data
