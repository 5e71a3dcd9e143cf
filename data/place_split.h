#pragma once
// Validation held out by place: datasets of several places (one import per place: SemanticKITTI
// sequence 00, sequence 08, the KITTI object drives, the nuScenes scene, RELLIS-3D), each held out
// in turn, trained on the others. A frame's place is its (source, sequence) (data/dataset.h
// FramePlace): frames of one place are consecutive scans of one drive, so they are never split
// between training and scoring. Only datasets on the held-out one's grid (rows x columns, so the
// network sees the same beam geometry) and intensity scale (data/intensity_scale.h: the 0-1 targets
// of two scales measure different things) can train for it; the others are excluded with a reason.
// A dataset holding a frame of the held-out place never trains for it.
#include <filesystem>
#include <string>
#include <vector>

#include "data/dataset.h"

namespace lidarsim::data {

struct PlacedSet {
  std::string name;                  // e.g. "seq00"
  std::filesystem::path path;        // the dataset file ("" for sets made in memory)
  std::vector<FramePlace> places;    // one per frame
  int rows = 0, cols = 0;
  IntensityScale scale;
};

// The frames' places, grid and scale of a dataset file (headers only).
PlacedSet read_placed_set(const std::string& name, const std::filesystem::path& path);

// "source/sequence": frames with the same key come from one place.
std::string place_key(const FramePlace& place);

struct PlaceFold {
  std::string held_out;               // a PlacedSet name
  std::vector<std::string> training;  // names of the sets that train; empty: none can
  std::vector<std::string> excluded;  // "name: reason" for every other set left out
};

// One fold per set, in the order given. Names must be unique and every set must have frames.
std::vector<PlaceFold> place_folds(const std::vector<PlacedSet>& sets);

// Throws (naming the set, frame and place) if a frame of `training` has a place of `held_out`.
void check_no_place_leak(const PlacedSet& held_out, const std::vector<PlacedSet>& training);

}  // namespace lidarsim::data
