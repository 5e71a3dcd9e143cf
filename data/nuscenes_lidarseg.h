#pragma once
// nuScenes-lidarseg: per-point class labels of LIDAR_TOP keyframes (Fong et al., Panoptic
// nuScenes). A label file holds one uint8 per point of its .pcd.bin, in the same order: the
// index of the nuScenes general 32-class taxonomy (0 noise ... 30 static.vegetation, 31
// vehicle.ego). Classes map to ours through a class table (data/ontologies/nuscenes-lidarseg.csv).
// Points of class 31 are the ego car's own roof and body, seen by the sensor on every sweep; they
// are dropped before projection (they say nothing about the scene and their intensity is the
// car's paint at 1-2 m).
//
// Folder layout read here (the one ../shared/data/nuscenes-lidarseg-scene has): velodyne/NNNNNN.pcd.bin
// with labels/NNNNNN.lidarseg.bin beside it. The official release names label files by the
// sample_data token (lidarseg/v1.0-*/<token>_lidarseg.bin), which needs the devkit's JSON tables
// to pair; that layout is not read.
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "data/class_table.h"
#include "data/dataset.h"
#include "data/import.h"
#include "pgm/projection.h"

namespace lidarsim::data {

inline constexpr int kNuscenesLidarsegClasses = 32;
inline constexpr int kNuscenesEgoClass = 31;  // vehicle.ego

// One uint8 per point; throws naming the file and field when the count differs from `points`
// (a truncated or foreign file) or a label is outside 0-31.
std::vector<std::uint8_t> read_nuscenes_lidarseg_labels(const std::filesystem::path& path, std::size_t points);

struct NuscenesLidarsegFiles {
  std::string id;  // "000000"
  std::filesystem::path pcd, labels;
};

// Every velodyne/*.pcd.bin of `dir` with its labels/*.lidarseg.bin, sorted by id; throws naming
// the scan whose label file is missing.
std::vector<NuscenesLidarsegFiles> list_nuscenes_lidarseg(const std::filesystem::path& dir);

struct NuscenesLidarsegScan {
  std::vector<pgm::Point> points;  // ego points dropped; class from the table, default material
  std::vector<std::filesystem::path> sources;
  std::size_t read = 0;                         // points in the file
  std::size_t ego = 0;                          // of them vehicle.ego, dropped
  std::vector<std::int64_t> file_index;         // per kept point, its index in the file
  std::map<std::string, std::size_t> unmapped;  // nuScenes class name -> points imported as unlabeled
};

NuscenesLidarsegScan read_nuscenes_lidarseg_scan(const NuscenesLidarsegFiles& files, const ClassTable& classes);

// The labelled frames of `dir` as a dataset on `layout` (data/sensors/hdl32e-nuscenes.json), rows
// by the recorded ring: import_dataset(SourceFormat::NuscenesLidarseg) with this layout and table
// (lidar-data import --nuscenes-lidarseg streams the same frames to a file). Frame ids
// "nuscenes/<folder name>/<id>", one place per folder (one scene); options.note is told the
// vehicle.ego points dropped and the points imported as unlabeled per nuScenes class.
Dataset import_nuscenes_lidarseg(const std::filesystem::path& dir, const pgm::BeamLayout& layout,
                                 const ClassTable& classes, const ImportOptions& options = {});

}  // namespace lidarsim::data
