#include "data/dataset_reader.h"

#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <type_traits>

#include "common/error.h"
#include "data/hdf5_io.h"
#include "nn/h5_memory_file.h"

namespace lidarsim::data {
namespace fs = std::filesystem;
static_assert(std::is_same_v<hid_t, std::int64_t>, "DatasetReader keeps HDF5 ids as int64");

namespace {

std::vector<std::string> json_strings(const std::string& text, const std::string& fname, const std::string& field) {
  try {
    return nlohmann::json::parse(text).get<std::vector<std::string>>();
  } catch (const nlohmann::json::exception&) {
    throw input_error(fname, field, "expected a JSON list of strings");
  }
}

void read_slab(hid_t ds, const std::string& fname, const char* name, hid_t type, int n, void* out) {
  h5::Id space(H5Dget_space(ds), H5Sclose);
  const int rank = H5Sget_simple_extent_ndims(space);
  std::vector<hsize_t> count(rank), start(rank, 0);
  H5Sget_simple_extent_dims(space, count.data(), nullptr);
  start[0] = static_cast<hsize_t>(n);
  count[0] = 1;
  H5Sselect_hyperslab(space, H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr);
  h5::Id mem(H5Screate_simple(rank, count.data(), nullptr), H5Sclose);
  if (H5Dread(ds, type, mem, space, H5P_DEFAULT, out) < 0)
    throw input_error(fname, std::string("dataset ") + name,
                      "frame " + std::to_string(n) + " cannot be read (damaged chunk, checksum mismatch or wrong type)");
}

}  // namespace

DatasetReader::DatasetReader(const fs::path& path, const std::vector<std::string>& required_channels)
    : fname_(path.string()) {
  h5::quiet();
  if (!fs::is_regular_file(path)) throw input_error(fname_, "file", "not found");
  if (H5Fis_hdf5(path.c_str()) <= 0) throw input_error(fname_, "file", "not an HDF5 file");
  file_ = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (file_ < 0) throw input_error(fname_, "file", "cannot be opened as HDF5");
  read_header(required_channels);
}

DatasetReader::DatasetReader(const nn::MemoryImage& image, const std::vector<std::string>& required_channels)
    : fname_(image.name.string()) {
  h5::quiet();
  // H5P_DEFAULT's settings, with the in-memory driver instead of the disk.
  h5::Id fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
  file_ = nn::open_memory_image(image, fapl);
  if (file_ < 0) throw input_error(fname_, "file", "cannot be opened as HDF5");
  read_header(required_channels);
}

void DatasetReader::read_header(const std::vector<std::string>& required_channels) {
  try {
    Dataset& d = header_;
    h5::Id root(H5Gopen2(file_, "/", H5P_DEFAULT), H5Gclose);
    if (h5::read_attr(root, fname_, "format") != "lidarsim-dataset")
      throw input_error(fname_, "attribute format", "expected 'lidarsim-dataset'");
    d.channels = json_strings(h5::read_attr(root, fname_, "channels"), fname_, "attribute channels");
    d.layout = pgm::BeamLayout::from_json(h5::read_attr(root, fname_, "beam_layout"), fname_ + ": attribute beam_layout");
    d.source_format = h5::read_attr(root, fname_, "source_format");
    if (h5::has_attr(root, "intensity_scale")) {
      d.intensity_scale.name = h5::read_attr(root, fname_, "intensity_scale");
      if (d.intensity_scale.name.empty()) throw input_error(fname_, "attribute intensity_scale", "empty");
      if (h5::has_attr(root, "intensity_normalisation"))
        d.intensity_scale.normalisation = h5::read_attr(root, fname_, "intensity_normalisation");
    }
    for (const auto& c : required_channels) {
      if (c == "mask" || c == "intensity") continue;  // /mask and /target
      if (std::find(d.channels.begin(), d.channels.end(), c) == d.channels.end()) {
        std::string have;
        for (const auto& a : d.channels) have += (have.empty() ? "" : ", ") + a;
        throw input_error(fname_, "/pgm channel '" + c + "'", "missing (the file has: " + have + ")");
      }
    }
    std::vector<hsize_t> dims;
    pgm_ = h5::open_checked(file_, fname_, "/pgm",
                            {-1, static_cast<long long>(d.channels.size()), d.layout.rows(), d.layout.columns}, dims);
    n_ = static_cast<int>(dims[0]);
    h_ = static_cast<int>(dims[2]);
    w_ = static_cast<int>(dims[3]);
    target_ = h5::open_checked(file_, fname_, "/target", {n_, 1, h_, w_}, dims);
    mask_ = h5::open_checked(file_, fname_, "/mask", {n_, 1, h_, w_}, dims);
    if (H5Lexists(file_, "/point_index", H5P_DEFAULT) > 0)
      point_index_ = h5::open_checked(file_, fname_, "/point_index", {n_, h_, w_}, dims);
    d.frames = h5::read_strings(file_, fname_, "/frames", n_);
    d.sources = h5::read_strings(file_, fname_, "/sources", -1);
    // Version 2 files keep the per-frame lists as datasets (an attribute cannot hold 100k entries).
    if (H5Lexists(file_, "/row_modes", H5P_DEFAULT) > 0) {
      d.row_modes = h5::read_strings(file_, fname_, "/row_modes", n_);
    } else {
      d.row_modes = json_strings(h5::read_attr(root, fname_, "row_modes"), fname_, "attribute row_modes");
      if (static_cast<int>(d.row_modes.size()) != n_)
        throw input_error(fname_, "attribute row_modes", "expected one entry per frame (" + std::to_string(n_) + ")");
    }
    if (H5Lexists(file_, "/place_source", H5P_DEFAULT) > 0) {
      const auto source = h5::read_strings(file_, fname_, "/place_source", n_);
      const auto sequence = h5::read_strings(file_, fname_, "/place_sequence", n_);
      const auto frame = h5::read_strings(file_, fname_, "/place_frame", n_);
      for (int i = 0; i < n_; ++i) d.places.push_back({source[i], sequence[i], frame[i]});
    }
  } catch (...) {
    for (hid_t ds : {pgm_, target_, mask_, point_index_})
      if (ds >= 0) H5Dclose(ds);
    H5Fclose(file_);
    throw;
  }
}

DatasetReader::~DatasetReader() {
  for (hid_t ds : {pgm_, target_, mask_, point_index_})
    if (ds >= 0) H5Dclose(ds);
  if (file_ >= 0) H5Fclose(file_);
}

void DatasetReader::read_frame(int n, float* pgm, float* target, float* mask, std::int32_t* point_index) const {
  h5::quiet();  // per thread: a prefetching thread would otherwise print HDF5's own error stack
  if (n < 0 || n >= n_) throw input_error(fname_, "frame " + std::to_string(n), "out of range (" + std::to_string(n_) + " frames)");
  const std::size_t plane = static_cast<std::size_t>(h_) * w_;
  read_slab(pgm_, fname_, "/pgm", H5T_NATIVE_FLOAT, n, pgm);
  read_slab(target_, fname_, "/target", H5T_NATIVE_FLOAT, n, target);
  mask_buf_.resize(plane);
  read_slab(mask_, fname_, "/mask", H5T_NATIVE_UINT8, n, mask_buf_.data());
  for (std::size_t i = 0; i < plane; ++i) mask[i] = mask_buf_[i] ? 1.f : 0.f;
  if (point_index) {
    if (point_index_ >= 0) read_slab(point_index_, fname_, "/point_index", H5T_NATIVE_INT32, n, point_index);
    else std::fill(point_index, point_index + plane, -1);
  }
  const std::size_t values = plane * header_.channels.size();
  for (std::size_t i = 0; i < values; ++i)
    if (!std::isfinite(pgm[i])) throw input_error(fname_, "/pgm", "contains NaN or Inf (frame " + std::to_string(n) + ")");
  for (std::size_t i = 0; i < plane; ++i)
    if (!std::isfinite(target[i])) throw input_error(fname_, "/target", "contains NaN or Inf (frame " + std::to_string(n) + ")");
}

}  // namespace lidarsim::data
