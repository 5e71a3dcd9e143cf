#pragma once
// RELLIS-3D Ouster OS1-64 scans, read as they are: the organized .bin (float32 x, y, z,
// intensity; 64 rings x 2048 columns stored column by column, point k in ring k % 64 with ring
// 0 the top beam; no return = the point (0, 0, 0)), its .label (uint32 per point, lower 16 bits
// the RELLIS class id), and, when found, the sensor's own PLY of the same scan, whose
// `reflectivity` becomes the intensity (the .bin's intensity is a rescaled value, max ~0.01).
// This firmware's reflectivity is 16-bit and not on the 0-255 scale of later Ouster firmware
// (returns of the sample: median 1538, 99th percentile 4679, max 59345), so intensity =
// reflectivity / kRellisReflectivityScale capped at 1: a fixed scale (not per scan), chosen so
// that only retro-reflectors saturate.
//
// Folder layouts: the dataset's (SEQ/os1_cloud_node_kitti_bin/NNNNNN.bin with
// SEQ/os1_cloud_node_semantickitti_label_id/NNNNNN.label and SEQ/os1_cloud_node_color_ply/
// frameNNNNNN-*.ply), or everything in one folder (the sample as the repository ships it).
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "data/class_table.h"
#include "pgm/projection.h"

namespace lidarsim::data {

inline constexpr int kRellisRings = 64;
inline constexpr double kRellisReflectivityScale = 4096;

struct Rellis3dFiles {
  std::string sequence;  // "00000" (the folder above the kitti_bin folder), or the folder's name
  std::string id;        // "000104"
  std::filesystem::path bin;
  std::optional<std::filesystem::path> label, ply;
};

// Every .bin under `dir` (one sequence folder, a folder of sequences, or one flat folder).
std::vector<Rellis3dFiles> list_rellis3d(const std::filesystem::path& dir);

struct Rellis3dScan {
  std::vector<pgm::Point> points;  // returns only, ring set, class from the table
  std::vector<std::filesystem::path> sources;
  std::size_t cells = 0;                   // points in the file (returns + no-returns)
  std::map<std::string, std::size_t> unmapped;  // RELLIS class name -> points imported as unlabeled
  bool reflectivity = false;               // intensity from the PLY's reflectivity
};

// Throws naming the file when the .bin is not 64 rings of whole columns, the label count
// differs, or the PLY's x, y, z differ from the .bin's.
Rellis3dScan read_rellis3d_scan(const Rellis3dFiles& files, const ClassTable& classes);

}  // namespace lidarsim::data
