#pragma once
// Train/validation splits for recorded scans. Consecutive scans are nearly identical, so azimuth
// regions are held out instead of scans; where the scans come from several places, whole frames
// (drives) are held out instead.
//
// Every cell gets a role: train (fitted on), validation (scored), or guard (neither).
//
// "guarded" (the default of lidar-train, lidar-data baselines and the intensity loop): a
//   network's output at a cell sees the inputs within its receptive field's half-width h
//   (nn/receptive_field.h). If a training cell and a scored cell see the same input column, the
//   network can learn the held-out scenery from the training side (interpolation, not
//   generalisation; the three SemanticKITTI scans show the same street, so a region's scenery
//   is in every scan at the same columns). So each validation region has a guard band of 2 h
//   columns on each side with no training loss and no score: a training cell's inputs and a
//   scored cell's inputs are then at least one column apart. Regions: 25 % of the columns. Two
//   opposite regions of W/8 columns centred at W/8 and 5W/8 (the front-left and back-right
//   diagonals; training is then the front-right and back-left diagonals, which the left-right
//   mirror augmentation maps onto the same kind of view: road ahead or behind beside a facade)
//   when they and their guards leave at least 25 % of the columns for training, else one region
//   of W/4, the front-left quadrant (the guard of a depth-4 UNet, 2 x 107 columns, does not fit
//   twice in 1024). At 1024 columns and the bundled recipe (base 8, depth 3: h = 51, guard 102):
//   regions [64, 192) and [576, 704), guards 102 wide, 360 training columns. (Regions centred on
//   the car's sides were tried first: they validate on near facades only while training sees
//   only the road ahead and behind, and the global mean's error rose from 0.111 to 0.153.)
// "interleaved" (the old reference split, kept by name for comparison only): 16 sectors, 3, 7,
//   11 and 15 validation in every scan, no guard. It leaks: a validation cell's receptive field
//   reaches into the neighbouring training sectors (tests/data/test_split_leak.cpp).
// "frames:ID,ID,...": frames whose id ends with one of the IDs are validation in every column,
//   all others train (KITTI object frames come from different drives: cross-place validation).
#include <cstdint>
#include <string>
#include <vector>

namespace lidarsim::data {

enum Role : std::uint8_t { kTrain = 0, kValidation = 1, kGuard = 2 };

struct SectorSplit {
  std::string name = "interleaved";
  int sectors = 16;
  std::vector<int> validation = {3, 7, 11, 15};
  // Guarded split: validation column ranges as fractions of the circle [begin, end) (wrapping),
  // and the guard band on each side in columns. Empty: the sectors above.
  std::vector<std::pair<double, double>> regions;
  int guard_columns = 0;
  // Frame hold-out: non-empty = whole frames validate (by id suffix), the rest train.
  std::vector<std::string> validation_frames;

  int sector_of(int column, int columns) const;  // throws unless columns is a multiple of sectors
  bool is_validation(int column, int columns) const;
  // Per column: 1 = validation, 0 = training (guard columns count as not validation).
  std::vector<std::uint8_t> validation_columns(int columns) const;
  // Per column of a frame with id `frame_id`: Role.
  std::vector<std::uint8_t> roles(int columns, const std::string& frame_id = "") const;
  // Index of the validation region (or sector) a column belongs to, -1 outside.
  int region_of(int column, int columns) const;
  std::string describe(int columns) const;
};

// The old interleaved split above (sectors 3, 7, 11, 15 of 16; no guard).
inline SectorSplit reference_split() { return {}; }
// The guarded split for a model with receptive-field half-width `half_width` at `columns`.
SectorSplit guarded_split(int half_width, int columns = 1024);
// "guarded" (guard for `half_width`), "guarded:H" (half-width H), "interleaved",
// "frames:ID,ID". Throws naming the spec.
SectorSplit parse_split(const std::string& spec, int half_width, int columns = 1024);

// Early stopping that cannot leak (lidar-train --early-stop): an inner validation region of
// `width` columns carved out of the training columns of a region split, on which the epoch is
// chosen; the scored regions are never looked at. No input column may be seen by two of {training
// cell, inner cell, scored cell}, so any two of them are more than 2 h columns apart. The guarded
// split's training arcs are too short for an inner region with its own 2 h band on both sides
// (depth 3: two arcs of 180 columns, 2 h = 102), so the inner region starts right after the end of
// a scored region's guard band (the first columns of the longest training arc): that band, 2 h
// wide, already separates it from the scored cells, and the inner region's own band of 2 h on the
// other side separates it from the training cells. Depth 3 at 1024 columns, width 32: inner
// [294, 326), band [326, 428), training [428, 474) and [806, 986): 226 columns. Throws unless the
// split has guarded regions and at least `width` training columns remain in that arc.
// Returned split: regions = the inner region, guard_columns = 2 h.
SectorSplit inner_split(const SectorSplit& scored, int half_width, int columns = 1024, int width = 32);
// The same for a frame hold-out (frames from different places, "frames:ID,..."): the inner set is
// whole training frames `ids` (other places than the scored ones; no guard needed, nothing is
// shared between frames). Throws unless `scored` holds out frames and no id names a scored frame.
SectorSplit inner_frames_split(const SectorSplit& scored, const std::vector<std::string>& ids);
// The split the network trains under with an inner region: the scored regions and the inner
// region are all held out, each with its guard bands.
SectorSplit with_inner(const SectorSplit& scored, const SectorSplit& inner);

}  // namespace lidarsim::data
