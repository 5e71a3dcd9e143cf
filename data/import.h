#pragma once
// Recorded scans -> HDF5 dataset (data/dataset.h). KITTI-family scans are projected onto the
// KITTI HDL-64E layout (pgm::BeamLayout::hdl64e) with pgm::project: rows by the azimuth-wrap
// cut when the scan is in firing order (KITTI .bin files are), nearest elevation otherwise;
// sensors that record a ring index use it. The row mode used is stored per frame. /pgm gets
// range, class, material and the extra channels; /target the reflectance; /mask the cells with
// a return.
//
// import_to_file streams: scans are read and projected a block at a time on every OpenMP
// thread, then appended in order to a DatasetWriter, so memory holds one block whatever the
// number of scans and the time per scan does not grow with it.
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "pgm/projection.h"

namespace lidarsim::data {

// The recorded formats import reads (names as on the command line and in /place_source).
//   semantickitti  DIR with sequences (data/semantickitti.h)
//   kitti_object   KITTI object training folder (data/kitti_object.h)
//   nuscenes       folder of LIDAR_TOP .pcd.bin sweeps (data/nuscenes.h); needs a layout
//   rellis3d       RELLIS-3D OS1-64 scans (data/rellis3d.h); needs a layout and a class table
//   ouster         one .pcap or a folder of them, each with its JSON metadata (data/ouster.h);
//                  the layout comes from the metadata. A pcap is decoded whole.
enum class SourceFormat { SemanticKitti, KittiObject, Nuscenes, Rellis3d, Ouster };
std::string to_string(SourceFormat format);
SourceFormat source_format_from_string(const std::string& name);  // throws naming the known ones

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
  // The grid to project onto; default: the format's own sensor (HDL-64E for KITTI).
  std::optional<pgm::BeamLayout> layout;
  int block = 0;  // scans read and projected together (0 = 4 per OpenMP thread)
  std::filesystem::path class_table;     // rellis3d: its ontology -> ours (data/ontologies/rellis3d.csv)
  std::filesystem::path ouster_metadata; // ouster: the JSON metadata (default: found beside the pcap)
  // Called after each frame with (done, total); e.g. a progress bar.
  std::function<void(int, int)> progress;
  // Called with notes worth telling a user (scans skipped for lack of labels, unknown labels).
  std::function<void(const std::string&)> note;
};

// Channels written to /pgm for these options.
std::vector<std::string> dataset_channels(const ImportOptions& options);

struct ImportSummary {
  int frames = 0;
  long long returns = 0;               // cells with a return
  std::map<std::string, int> row_modes;  // frames per row mode used
  pgm::BeamLayout layout;
  std::vector<std::string> channels;
};

// Streams every scan of `dir` into the dataset file `out` (written atomically: nothing appears
// at `out` unless the whole import succeeds). Throws lidarsim::Error naming the file at fault;
// an error when no frame qualifies.
ImportSummary import_to_file(SourceFormat format, const std::filesystem::path& dir, const std::filesystem::path& out,
                             const ImportOptions& options = {});

// In memory, for small sets (tests, calibration): the same frames as import_to_file.
Dataset import_dataset(SourceFormat format, const std::filesystem::path& dir, const ImportOptions& options = {});
Dataset import_semantickitti(const std::filesystem::path& dir, const ImportOptions& options = {});
Dataset import_kitti_object(const std::filesystem::path& dir, const ImportOptions& options = {});

}  // namespace lidarsim::data
