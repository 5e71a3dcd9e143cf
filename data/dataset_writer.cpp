#include "data/dataset_writer.h"

#include <fcntl.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "common/error.h"
#include "data/hdf5_io.h"
#include "nn/h5_memory_file.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

namespace {

// HDF5 keeps attributes in the object header (64 KB); a per-frame list that long goes only to
// the /row_modes dataset. Readers look there first.
constexpr std::size_t kMaxListAttribute = 48 * 1024;

// An extendible dataset of frames: [0, rest...] growing along axis 0, one frame per chunk.
hid_t create_frames(hid_t file, const std::string& fname, const char* name, hid_t type, std::vector<hsize_t> frame) {
  std::vector<hsize_t> dims = {0}, max = {H5S_UNLIMITED}, chunk = {1};
  for (hsize_t d : frame) {
    dims.push_back(d);
    max.push_back(d);
    chunk.push_back(d);
  }
  h5::Id space(H5Screate_simple(static_cast<int>(dims.size()), dims.data(), max.data()), H5Sclose);
  h5::Id plist(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
  H5Pset_chunk(plist, static_cast<int>(chunk.size()), chunk.data());
  H5Pset_shuffle(plist);
  H5Pset_deflate(plist, 4);
  // Fletcher-32 last, so it sums each compressed chunk as stored; HDF5 checks it on every read.
  if (!nn::add_checksum(plist, static_cast<int>(chunk.size()), chunk.data()))
    throw input_error(fname, name, "cannot set up the checksum filter");
  hid_t ds = H5Dcreate2(file, name, type, space, H5P_DEFAULT, plist, H5P_DEFAULT);
  if (ds < 0) throw input_error(fname, name, "cannot create dataset");
  return ds;
}

void append_frame(hid_t ds, const std::string& fname, const char* name, hid_t type, hsize_t n, const void* data) {
  h5::Id old_space(H5Dget_space(ds), H5Sclose);
  const int rank = H5Sget_simple_extent_ndims(old_space);
  std::vector<hsize_t> dims(rank);
  H5Sget_simple_extent_dims(old_space, dims.data(), nullptr);
  dims[0] = n + 1;
  h5::check(H5Dset_extent(ds, dims.data()), fname, name);
  h5::Id space(H5Dget_space(ds), H5Sclose);
  std::vector<hsize_t> start(rank, 0), count = dims;
  start[0] = n;
  count[0] = 1;
  H5Sselect_hyperslab(space, H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr);
  h5::Id mem(H5Screate_simple(rank, count.data(), nullptr), H5Sclose);
  h5::check(H5Dwrite(ds, type, mem, space, H5P_DEFAULT, data), fname, name);
}

// The temporary file, written by HDF5's default (sec2) driver. Format pinned to HDF5 1.10:
// checksummed object headers, superblock and chunk index; links and attributes kept in the
// header (nn::keep_compact). STRONG close degree: closing the file closes what is open in it.
hid_t create_file(const std::string& temp) {
  h5::Id fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose), fcpl(H5Pcreate(H5P_FILE_CREATE), H5Pclose);
  if (!fapl.ok() || !fcpl.ok() || H5Pset_libver_bounds(fapl, H5F_LIBVER_V110, H5F_LIBVER_V110) < 0 ||
      H5Pset_fclose_degree(fapl, H5F_CLOSE_STRONG) < 0 || !nn::keep_compact(fcpl))
    return -1;
  return H5Fcreate(temp.c_str(), H5F_ACC_TRUNC, fcpl, fapl);
}

}  // namespace

struct DatasetWriter::Impl {
  explicit Impl(const fs::path& path) : out(path), fname(path.string()) {}
  AtomicFile out;
  std::string fname;
  hid_t file = -1, pgm = -1, target = -1, mask = -1, point_index = -1;
  std::vector<float> pgm_buf;
  std::vector<std::uint8_t> mask_buf;
  std::vector<std::int32_t> index_buf;

  // Gives up the temporary file (a failed write, flush or close, or no commit). HDF5 1.10 keeps a
  // file whose close failed in its id table, half torn down, and its exit handler then crashes
  // on it (segfault in H5F__close_cb): so the close must not fail. The file is discarded anyway,
  // so its descriptor is pointed at /dev/null first (writes there cannot fail on a full disk),
  // then every id still open in the file is closed, the file flushed once more (without this
  // flush, HDF5 1.10.8's close still failed after an earlier failed flush) and closed.
  // AtomicFile removes the temporary afterwards.
  void abandon() {
    if (file < 0) return;
    void* handle = nullptr;
    if (H5Fget_vfd_handle(file, H5P_DEFAULT, &handle) >= 0 && handle) {
      const int null = ::open("/dev/null", O_RDWR | O_CLOEXEC);
      if (null >= 0) {
        ::dup2(null, *static_cast<int*>(handle));
        ::close(null);
      }
    }
    for (hid_t* ds : {&pgm, &target, &mask, &point_index})
      if (*ds >= 0) H5Dclose(*ds), *ds = -1;
    const ssize_t open_ids = H5Fget_obj_count(file, H5F_OBJ_LOCAL | H5F_OBJ_DATASET | H5F_OBJ_GROUP | H5F_OBJ_DATATYPE | H5F_OBJ_ATTR);
    if (open_ids > 0) {
      std::vector<hid_t> ids(static_cast<std::size_t>(open_ids));
      const ssize_t got = H5Fget_obj_ids(file, H5F_OBJ_LOCAL | H5F_OBJ_DATASET | H5F_OBJ_GROUP | H5F_OBJ_DATATYPE | H5F_OBJ_ATTR,
                                         ids.size(), ids.data());
      for (ssize_t i = 0; i < got; ++i) H5Idec_ref(ids[static_cast<std::size_t>(i)]);
    }
    H5Fflush(file, H5F_SCOPE_GLOBAL);
    H5Fclose(file);
    file = -1;
  }
  ~Impl() { abandon(); }
};

DatasetWriter::DatasetWriter(const fs::path& path, std::vector<std::string> channels, pgm::BeamLayout layout,
                             std::string source_format, bool with_point_index)
    : impl_(std::make_unique<Impl>(path)),
      channels_(std::move(channels)),
      layout_(std::move(layout)),
      source_format_(std::move(source_format)) {
  h5::quiet();
  layout_.validate(path.string() + ": beam layout");
  Impl& m = *impl_;
  m.file = create_file(m.out.temp_path().string());
  if (m.file < 0) throw input_error(m.fname, "file", "cannot be created");
  const hsize_t c = channels_.size(), h = layout_.rows(), w = layout_.columns;
  m.pgm = create_frames(m.file, m.fname, "/pgm", H5T_NATIVE_FLOAT, {c, h, w});
  m.target = create_frames(m.file, m.fname, "/target", H5T_NATIVE_FLOAT, {1, h, w});
  m.mask = create_frames(m.file, m.fname, "/mask", H5T_NATIVE_UINT8, {1, h, w});
  if (with_point_index) m.point_index = create_frames(m.file, m.fname, "/point_index", H5T_NATIVE_INT32, {h, w});
}

DatasetWriter::~DatasetWriter() = default;

void DatasetWriter::append(const pgm::PolarGridMap& map, const std::string& frame_id, const std::string& row_mode,
                           const FramePlace& place) {
  if (!(map.layout() == layout_))
    throw Error(impl_->fname + ": frame " + frame_id + ": beam layout differs from the dataset's (" + layout_.name + ")");
  const std::size_t plane = map.cells();
  auto& buf = impl_->pgm_buf;
  buf.resize(plane * channels_.size());
  for (std::size_t c = 0; c < channels_.size(); ++c) {
    const float* src = map.channel(channels_[c]);
    std::copy(src, src + plane, buf.data() + c * plane);
  }
  auto& index = impl_->index_buf;
  index.resize(plane);
  for (std::size_t i = 0; i < plane; ++i) index[i] = static_cast<std::int32_t>(map.point_index()[i]);
  append(buf.data(), map.channel("intensity"), map.channel("mask"), index.data(), frame_id, row_mode, place);
}

void DatasetWriter::append(const float* pgm, const float* target, const float* mask, const std::int32_t* point_index,
                           const std::string& frame_id, const std::string& row_mode, const FramePlace& place) {
  Impl& m = *impl_;
  if (m.file < 0) throw input_error(m.fname, "file", "already committed");
  const hsize_t n = frames_.size();
  const std::size_t plane = static_cast<std::size_t>(layout_.rows()) * layout_.columns;
  m.mask_buf.resize(plane);
  for (std::size_t i = 0; i < plane; ++i) {
    m.mask_buf[i] = mask[i] > 0 ? 1 : 0;
    returns_ += m.mask_buf[i];
  }
  append_frame(m.pgm, m.fname, "/pgm", H5T_NATIVE_FLOAT, n, pgm);
  append_frame(m.target, m.fname, "/target", H5T_NATIVE_FLOAT, n, target);
  append_frame(m.mask, m.fname, "/mask", H5T_NATIVE_UINT8, n, m.mask_buf.data());
  if (m.point_index >= 0) {
    if (!point_index) throw input_error(m.fname, "/point_index", "frame " + frame_id + " has none");
    append_frame(m.point_index, m.fname, "/point_index", H5T_NATIVE_INT32, n, point_index);
  }
  frames_.push_back(frame_id);
  row_modes_.push_back(row_mode);
  places_.push_back(place);
  ++mode_counts_[row_mode];
}

void DatasetWriter::commit() {
  Impl& m = *impl_;
  if (m.file < 0) throw input_error(m.fname, "file", "already committed");
  h5::write_strings(m.file, m.fname, "/frames", frames_);
  h5::write_strings(m.file, m.fname, "/sources", sources_);
  h5::write_strings(m.file, m.fname, "/row_modes", row_modes_);
  std::vector<std::string> source, sequence, frame;
  for (const auto& p : places_) {
    source.push_back(p.source);
    sequence.push_back(p.sequence);
    frame.push_back(p.frame);
  }
  h5::write_strings(m.file, m.fname, "/place_source", source);
  h5::write_strings(m.file, m.fname, "/place_sequence", sequence);
  h5::write_strings(m.file, m.fname, "/place_frame", frame);
  {
    h5::Id root(H5Gopen2(m.file, "/", H5P_DEFAULT), H5Gclose);
    h5::write_attr(root, m.fname, "format", "lidarsim-dataset");
    h5::write_attr_int(root, m.fname, "version", 2);
    h5::write_attr(root, m.fname, "channels", nlohmann::json(channels_).dump());
    h5::write_attr(root, m.fname, "beam_layout", layout_.to_json());
    h5::write_attr(root, m.fname, "source_format", source_format_);
    const std::string modes = nlohmann::json(row_modes_).dump();
    if (modes.size() <= kMaxListAttribute) h5::write_attr(root, m.fname, "row_modes", modes);
    h5::write_attr(root, m.fname, "target_channel", "intensity");
    if (intensity_scale_.recorded()) {
      h5::write_attr(root, m.fname, "intensity_scale", intensity_scale_.name);
      h5::write_attr(root, m.fname, "intensity_normalisation", intensity_scale_.normalisation);
    }
  }
  // Everything is written by the flush; a failure there leaves the file open for abandon() (the
  // destructor). After a good flush, the close rewrites little more than the superblock, inside
  // the file's current size.
  if (H5Fflush(m.file, H5F_SCOPE_GLOBAL) < 0) throw input_error(m.fname, "file", "cannot be written (disk full?)");
  bool closed = true;
  for (hid_t* ds : {&m.pgm, &m.target, &m.mask, &m.point_index})
    if (*ds >= 0) closed = H5Dclose(*ds) >= 0 && closed, *ds = -1;
  closed = H5Fclose(m.file) >= 0 && closed;
  m.file = -1;
  if (!closed) throw input_error(m.fname, "file", "cannot be closed (disk full?)");
  m.out.commit();
}

}  // namespace lidarsim::data
