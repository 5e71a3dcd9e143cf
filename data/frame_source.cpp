#include "data/frame_source.h"

#include <hdf5.h>

#include <algorithm>
#include <atomic>
#include <mutex>

#include "common/error.h"
#include "data/dataset_reader.h"

namespace lidarsim::data {
namespace {

struct FrameArrays {
  std::vector<float> pgm, target, mask;
};

class FileFrameSource : public FrameSource {
 public:
  FileFrameSource(const std::filesystem::path& path, const std::vector<std::string>& required, std::size_t cache_bytes)
      : reader_(path, required), cache_bytes_(cache_bytes), cache_(static_cast<std::size_t>(reader_.size())) {
    // All or nothing: a shuffled pass over a set larger than the cache would find a cached frame
    // rarely, and the cache would only add its size to the process's memory.
    const std::size_t plane = static_cast<std::size_t>(rows()) * cols();
    if ((header().channels.size() + 2) * plane * sizeof(float) * static_cast<std::size_t>(size()) > cache_bytes_)
      cache_bytes_ = 0;
  }
  const Dataset& header() const override { return reader_.header(); }
  int size() const override { return reader_.size(); }
  int rows() const override { return reader_.rows(); }
  int cols() const override { return reader_.cols(); }
  const std::string& name() const override { return reader_.path(); }
  bool reads_overlap_other_hdf5() const override {
    hbool_t safe = 0;
    return H5is_library_threadsafe(&safe) >= 0 && safe;
  }

  FrameRef frame(int n) const override {
    // One reader at a time: DatasetReader keeps a scratch buffer, and HDF5 serialises calls anyway.
    std::lock_guard<std::mutex> lock(mutex_);
    std::shared_ptr<const FrameArrays> arrays;
    if (n >= 0 && n < size() && cache_[static_cast<std::size_t>(n)]) {
      arrays = cache_[static_cast<std::size_t>(n)];
    } else {
      std::shared_ptr<FrameArrays> fresh = recycled();
      const std::size_t plane = static_cast<std::size_t>(rows()) * cols();
      fresh->pgm.resize(plane * header().channels.size());
      fresh->target.resize(plane);
      fresh->mask.resize(plane);
      reader_.read_frame(n, fresh->pgm.data(), fresh->target.data(), fresh->mask.data());
      const std::size_t bytes = (fresh->pgm.size() + 2 * plane) * sizeof(float);
      if (cached_ + bytes <= cache_bytes_) {  // kept for good: out of the pool
        pool_.erase(std::remove(pool_.begin(), pool_.end(), fresh), pool_.end());
        cache_[static_cast<std::size_t>(n)] = fresh;
        cached_ += bytes;
      }
      arrays = std::move(fresh);
    }
    return {arrays->pgm.data(), arrays->target.data(), arrays->mask.data(), arrays};
  }

 private:
  // Arrays of a frame that nobody holds any more, to be overwritten: reading into fresh ones
  // costs as much in page faults as the decompression.
  std::shared_ptr<FrameArrays> recycled() const {
    for (const auto& arrays : pool_)
      if (arrays.use_count() == 1) {  // only the pool holds it; nobody else can take it (mutex_)
        std::atomic_thread_fence(std::memory_order_acquire);  // the last holder's reads come first
        return arrays;
      }
    auto fresh = std::make_shared<FrameArrays>();
    if (pool_.size() < kPool) pool_.push_back(fresh);
    return fresh;
  }
  static constexpr std::size_t kPool = 8;  // a batch in use, the next one being read, validation

  DatasetReader reader_;
  std::size_t cache_bytes_;
  mutable std::mutex mutex_;
  mutable std::vector<std::shared_ptr<const FrameArrays>> cache_;
  mutable std::size_t cached_ = 0;
  mutable std::vector<std::shared_ptr<FrameArrays>> pool_;
};

class MemoryFrameSource : public FrameSource {
 public:
  MemoryFrameSource(const Dataset& d, std::string name) : d_(d), name_(std::move(name)) {
    header_.channels = d.channels;
    header_.layout = d.layout;
    header_.source_format = d.source_format;
    header_.intensity_scale = d.intensity_scale;
    header_.frames = d.frames;
    header_.row_modes = d.row_modes;
    header_.sources = d.sources;
    header_.places = d.places;
  }
  const Dataset& header() const override { return header_; }
  int size() const override { return d_.size(); }
  int rows() const override { return d_.rows(); }
  int cols() const override { return d_.cols(); }
  const std::string& name() const override { return name_; }
  FrameRef frame(int n) const override {
    if (n < 0 || n >= size())
      throw input_error(name_, "frame " + std::to_string(n), "out of range (" + std::to_string(size()) + " frames)");
    return {d_.pgm.image(n), d_.target.image(n), d_.mask.image(n), nullptr};
  }

 private:
  const Dataset& d_;
  Dataset header_;
  std::string name_;
};

}  // namespace

pgm::ChannelView FrameSource::view(const FrameRef& f) const {
  pgm::ChannelView v;
  v.names = &header().channels;
  v.data = f.pgm;
  v.rows = rows();
  v.cols = cols();
  v.mask = f.mask;
  return v;
}

std::unique_ptr<FrameSource> open_frame_source(const std::filesystem::path& path,
                                               const std::vector<std::string>& required_channels,
                                               std::size_t cache_bytes) {
  return std::make_unique<FileFrameSource>(path, required_channels, cache_bytes);
}

std::unique_ptr<FrameSource> memory_frame_source(const Dataset& dataset, const std::string& name) {
  return std::make_unique<MemoryFrameSource>(dataset, name);
}

}  // namespace lidarsim::data
