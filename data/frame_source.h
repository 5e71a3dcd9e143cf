#pragma once
// Frames of a dataset one at a time: what a training step or a validation pass asks for (frame
// n, never the whole set), whether the frames stay in the file until asked for (DatasetReader:
// one hyperslab per frame array) or are already in memory. A data-parallel rank asks only for
// its own samples.
#include <cstddef>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "pgm/encoder.h"

namespace lidarsim::data {

// One frame's arrays as stored: pgm [C*H*W] (the header's channels), target and mask [H*W]
// (mask 0/1). `keep` owns them when they were read from a file.
struct FrameRef {
  const float* pgm = nullptr;
  const float* target = nullptr;
  const float* mask = nullptr;
  std::shared_ptr<const void> keep;
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Channels, layout, frame ids and places; no frame arrays.
  virtual const Dataset& header() const = 0;
  virtual int size() const = 0;
  virtual int rows() const = 0;
  virtual int cols() const = 0;
  // Names the source in errors (the file).
  virtual const std::string& name() const = 0;
  // Frame n; safe to call from several threads. Errors name the file, the array and the frame.
  virtual FrameRef frame(int n) const = 0;
  // Whether frame() may run on one thread while another thread uses HDF5 (e.g. writes a
  // checkpoint): false for files when the HDF5 library is not built thread-safe.
  virtual bool reads_overlap_other_hdf5() const { return true; }
  // Raw channels of a frame of this source, ready for pgm::encode_input.
  pgm::ChannelView view(const FrameRef& f) const;
};

// Reads frames from the file on demand. A file whose frames all fit in `cache_bytes` keeps each
// frame once read (read once, then from memory); a larger one keeps none.
std::unique_ptr<FrameSource> open_frame_source(const std::filesystem::path& path,
                                               const std::vector<std::string>& required_channels = {},
                                               std::size_t cache_bytes = 0);

// Frames of a dataset in memory (borrowed: it must outlive the source); `name` for errors.
std::unique_ptr<FrameSource> memory_frame_source(const Dataset& dataset, const std::string& name);

}  // namespace lidarsim::data
