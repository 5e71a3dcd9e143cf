#pragma once
// Streams frames into a dataset file (layout: data/dataset.h) one at a time, so an import holds
// one block of scans in memory whatever its length. Frame arrays are chunked one frame per
// chunk along the first axis (the unit a training step reads back), byte-shuffled and deflated:
// most cells repeat (empty cells, class ids), and shuffle puts the equal high bytes of floats
// side by side. Everything goes to a temporary file renamed by commit(); a writer destroyed
// without commit() leaves nothing behind.
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "pgm/beam_layout.h"
#include "pgm/polar_grid_map.h"

namespace lidarsim::data {

class DatasetWriter {
 public:
  // `channels` are the /pgm channel names; every frame must carry them plus "intensity" and
  // "mask". `with_point_index` adds /point_index.
  DatasetWriter(const std::filesystem::path& path, std::vector<std::string> channels, pgm::BeamLayout layout,
                std::string source_format, bool with_point_index = true);
  ~DatasetWriter();
  DatasetWriter(const DatasetWriter&) = delete;
  DatasetWriter& operator=(const DatasetWriter&) = delete;

  // One projected frame (its layout must equal the writer's).
  void append(const pgm::PolarGridMap& map, const std::string& frame_id, const std::string& row_mode,
              const FramePlace& place);
  // One frame from raw planes: pgm [C*H*W], target and mask [H*W], point_index [H*W] or null.
  void append(const float* pgm, const float* target, const float* mask, const std::int32_t* point_index,
              const std::string& frame_id, const std::string& row_mode, const FramePlace& place);
  void add_source(const std::string& file) { sources_.push_back(file); }
  // Written as the intensity_scale / intensity_normalisation attributes when recorded.
  void set_intensity_scale(IntensityScale scale) { intensity_scale_ = std::move(scale); }

  int size() const { return static_cast<int>(frames_.size()); }
  long long returns() const { return returns_; }  // cells with a return so far
  const std::map<std::string, int>& row_mode_counts() const { return mode_counts_; }

  // Writes the per-frame lists and the root attributes, flushes and renames into place.
  void commit();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::vector<std::string> channels_;
  pgm::BeamLayout layout_;
  std::string source_format_;
  IntensityScale intensity_scale_;
  std::vector<std::string> frames_, row_modes_, sources_;
  std::vector<FramePlace> places_;
  std::map<std::string, int> mode_counts_;
  long long returns_ = 0;
};

}  // namespace lidarsim::data
