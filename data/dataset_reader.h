#pragma once
// Reads a dataset file (layout: data/dataset.h) without loading its frames: the lists and
// attributes on open, then any frame on demand by a hyperslab read of its chunk. What a lazy
// training step or `lidar-data info` needs; read_dataset() is built on it.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "nn/memory_image.h"

namespace lidarsim::data {

class DatasetReader {
 public:
  // Checks the attributes, the shapes of every frame array and the per-frame lists;
  // `required_channels` must be in /pgm (the error names the file and the channel).
  explicit DatasetReader(const std::filesystem::path& path, const std::vector<std::string>& required_channels = {});
  // The same checks on a file's bytes in memory (the fuzz target reads each input so); errors
  // name image.name.
  explicit DatasetReader(const nn::MemoryImage& image, const std::vector<std::string>& required_channels = {});
  ~DatasetReader();
  DatasetReader(const DatasetReader&) = delete;
  DatasetReader& operator=(const DatasetReader&) = delete;

  // Everything but the frame arrays (pgm/target/mask empty, point_index empty).
  const Dataset& header() const { return header_; }
  int size() const { return n_; }
  int rows() const { return h_; }
  int cols() const { return w_; }
  int channels() const { return static_cast<int>(header_.channels.size()); }
  bool has_point_index() const { return point_index_ >= 0; }
  const std::string& path() const { return fname_; }

  // Frame n: pgm [C*H*W], target and mask [H*W] (0/1), point_index [H*W] (may be null; -1s
  // when the file has none). Throws naming the file when a value is NaN or Inf.
  void read_frame(int n, float* pgm, float* target, float* mask, std::int32_t* point_index = nullptr) const;

 private:
  void read_header(const std::vector<std::string>& required_channels);  // closes the file on an error

  std::string fname_;
  Dataset header_;
  int n_ = 0, h_ = 0, w_ = 0;
  std::int64_t file_ = -1, pgm_ = -1, target_ = -1, mask_ = -1, point_index_ = -1;
  mutable std::vector<std::uint8_t> mask_buf_;
};

// read_dataset (data/dataset.h) on a file's bytes in memory (the fuzz target); errors name
// image.name.
Dataset read_dataset(const nn::MemoryImage& image, const std::vector<std::string>& required_channels = {});

}  // namespace lidarsim::data
