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
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "data/class_table.h"
#include "data/dataset.h"
#include "data/intensity_scale.h"
#include "pgm/projection.h"

namespace lidarsim::data {

// The recorded formats import reads (names as on the command line and in /place_source).
//   semantickitti  DIR with sequences (data/semantickitti.h)
//   kitti_object   KITTI object training folder (data/kitti_object.h)
//   nuscenes       folder of LIDAR_TOP .pcd.bin sweeps (data/nuscenes.h); needs a layout
//   rellis3d       RELLIS-3D OS1-64 scans (data/rellis3d.h); needs a layout and a class table
//   ouster         one .pcap or a folder of them, each with its JSON metadata (data/ouster.h);
//                  the layout comes from the metadata. A pcap is decoded whole.
//   nuscenes_lidarseg  velodyne/*.pcd.bin with labels/*.lidarseg.bin (data/nuscenes_lidarseg.h);
//                  needs a layout and a class table; the ego car's points are dropped
//   semantickitti_mos  SemanticKITTI scans with moving-object labels only (data/semantickitti_mos.h):
//                  class unlabeled, and a "motion" channel (0 static, 1 movable, 2 moving)
// Places (/place_source) name where a frame was recorded, not how it is labelled: frames of the
// last two formats are places of "nuscenes" and "semantickitti".
enum class SourceFormat { SemanticKitti, KittiObject, Nuscenes, Rellis3d, Ouster, NuscenesLidarseg, SemanticKittiMos };
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
  // rellis3d, nuscenes_lidarseg: their ontology -> ours (data/ontologies/rellis3d.csv,
  // nuscenes-lidarseg.csv); `classes`, when set, is the table already read and wins.
  std::filesystem::path class_table;
  std::shared_ptr<const ClassTable> classes;
  std::filesystem::path ouster_metadata; // ouster: the JSON metadata (default: found beside the pcap)
  // Called after each frame with (done, total); e.g. a progress bar.
  std::function<void(int, int)> progress;
  // Called with notes worth telling a user (scans skipped for lack of labels, unknown labels).
  std::function<void(const std::string&)> note;
};

// Channels written to /pgm for these options.
std::vector<std::string> dataset_channels(const ImportOptions& options);
// ... and for this format: the options' channels plus those its reader adds ("motion").
std::vector<std::string> dataset_channels(SourceFormat format, const ImportOptions& options);

// The recorded intensity scale of a format's scans (data/intensity_scale.h); RELLIS-3D scans
// without their PLY have another one (import refuses to mix the two in one file).
IntensityScale intensity_scale_of(SourceFormat format);

struct ImportSummary {
  int frames = 0;
  long long returns = 0;               // cells with a return
  std::map<std::string, int> row_modes;  // frames per row mode used
  pgm::BeamLayout layout;
  std::vector<std::string> channels;
  IntensityScale intensity_scale;
  // Points of the imported scans (before projection keeps the nearest per cell).
  long long points = 0;                         // in the scan files
  long long dropped_points = 0;                 // not imported (nuscenes_lidarseg: vehicle.ego)
  std::map<std::string, long long> classes;     // our class name -> points imported
  std::map<std::string, long long> unmapped;    // foreign class -> points imported as unlabeled
  std::map<std::string, long long> motion;      // semantickitti_mos: static / movable / moving -> points
};

// Streams every scan of `dir` into the dataset file `out` (written atomically: nothing appears
// at `out` unless the whole import succeeds). Throws lidarsim::Error naming the file at fault;
// an error when no frame qualifies.
ImportSummary import_to_file(SourceFormat format, const std::filesystem::path& dir, const std::filesystem::path& out,
                             const ImportOptions& options = {});

// In memory, for small sets (tests, calibration): the same frames as import_to_file; `summary`,
// when given, gets the same counts.
Dataset import_dataset(SourceFormat format, const std::filesystem::path& dir, const ImportOptions& options = {},
                       ImportSummary* summary = nullptr);
Dataset import_semantickitti(const std::filesystem::path& dir, const ImportOptions& options = {});
Dataset import_kitti_object(const std::filesystem::path& dir, const ImportOptions& options = {});

}  // namespace lidarsim::data
