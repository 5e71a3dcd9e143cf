#pragma once
// The places of measured scans the return model's commands take (`lidar-qualify returns`, `loop
// returns`): --place NAME=FORMAT:DIR, a NAME given again adding a folder to that place (one drive
// recorded in several folders), each folder imported and turned into return targets
// (pgm::return_target: which empty cells had geometry).
#include <filesystem>
#include <string>
#include <vector>

#include "pgm/beam_layout.h"
#include "pgm/return_target.h"

namespace lidarsim::qualify {

struct ReturnPlace {
  std::string name, format;  // FORMAT: semantickitti | kitti_object | rellis3d | nuscenes_lidarseg
  std::vector<std::filesystem::path> dirs;
  pgm::BeamLayout layout;
  std::vector<pgm::ReturnTarget> targets;  // one per scan, in folder order
  std::vector<double> heights;             // sensor height per scan (estimated or given)
};

// Throws naming the spec for a malformed one, a name given with two formats.
std::vector<ReturnPlace> parse_return_places(const std::vector<std::string>& specs);

// Imports every folder of `p` and computes its return targets; throws naming the folder whose beam
// layout differs from the first's, or an unknown format.
void load_return_place(ReturnPlace& p, const pgm::ReturnTargetOptions& rule = {});

}  // namespace lidarsim::qualify
