#pragma once
// An HDF5 file's bytes already in memory, e.g. a fuzz input: the readers that take one
// (checkpoint, dataset) do exactly what they do with a path, without a file per input; `name`
// stands for the file in their errors. Opened by nn/h5_memory_file.h's open_memory_image.
#include <cstddef>
#include <filesystem>

namespace lidarsim::nn {

struct MemoryImage {
  const void* data = nullptr;
  std::size_t size = 0;
  std::filesystem::path name;
};

}  // namespace lidarsim::nn
