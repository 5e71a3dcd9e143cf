#pragma once
// Recorded scans -> HDF5 dataset (data/dataset.h). Every scan is projected onto the KITTI
// HDL-64E layout (pgm::BeamLayout::hdl64e) with pgm::project: rows by the azimuth-wrap cut when
// the scan is in firing order (KITTI .bin files are), nearest elevation otherwise; the row mode
// used is stored per frame. /pgm gets range, class, material and the extra channels; /target
// the reflectance; /mask the cells with a return.
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "pgm/projection.h"

namespace lidarsim::data {

struct ImportOptions {
  int columns = 1024;
  pgm::RowMode row_mode = pgm::RowMode::Auto;
  std::vector<std::string> extra_channels = {"elevation", "azimuth", "height", "incidence"};
  std::vector<std::string> sequences;  // SemanticKITTI: only these sequences (empty = all)
  int first = 0;                       // skip this many frames (after sorting)
  int max_frames = 0;                  // 0 = all
  bool include_unlabelled = false;     // SemanticKITTI scans without a .label (class 0 everywhere)
  bool skip_unreadable = false;        // a listed scan that cannot be read: skipped and noted (else an Error)
  float min_range = 0.f;
  // Called after each frame with (done, total); e.g. a progress bar.
  std::function<void(int, int)> progress;
  // Called with notes worth telling a user (scans skipped for lack of labels, unknown labels).
  std::function<void(const std::string&)> note;
};

// Channels written to /pgm for these options.
std::vector<std::string> dataset_channels(const ImportOptions& options);

// Throws lidarsim::Error naming the file at fault; an error when no frame qualifies.
Dataset import_semantickitti(const std::filesystem::path& dir, const ImportOptions& options = {});
Dataset import_kitti_object(const std::filesystem::path& dir, const ImportOptions& options = {});

}  // namespace lidarsim::data
