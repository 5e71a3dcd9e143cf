#include "data/dataset.h"

#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>

#include "common/error.h"
#include "nn/h5_memory_file.h"

namespace lidarsim::data {
namespace fs = std::filesystem;

namespace {

// Owns one HDF5 id and closes it with the matching function.
class H5 {
 public:
  H5(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  ~H5() {
    if (id_ >= 0) close_(id_);
  }
  H5(const H5&) = delete;
  H5& operator=(const H5&) = delete;
  operator hid_t() const { return id_; }
  bool ok() const { return id_ >= 0; }
  hid_t release() {
    const hid_t id = id_;
    id_ = -1;
    return id;
  }

 private:
  hid_t id_;
  herr_t (*close_)(hid_t);
};

void quiet() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

void check(herr_t status, const std::string& file, const std::string& what) {
  if (status < 0) throw input_error(file, what, "HDF5 write failed");
}

void write_array(hid_t file, const std::string& fname, const char* name, hid_t type, const std::vector<hsize_t>& dims,
                 const void* data) {
  H5 space(H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr), H5Sclose);
  H5 plist(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
  // Chunk per frame and compress: most cells of a range image repeat (empty, class ids).
  std::vector<hsize_t> chunk = dims;
  chunk[0] = 1;
  bool any = true;
  for (hsize_t d : dims) any = any && d > 0;
  if (any) {
    H5Pset_chunk(plist, static_cast<int>(chunk.size()), chunk.data());
    H5Pset_deflate(plist, 4);
    // Fletcher-32 on each compressed chunk: HDF5 checks it on every read (issue 13).
    if (!nn::add_checksum(plist, static_cast<int>(chunk.size()), chunk.data()))
      throw input_error(fname, name, "cannot set up the checksum filter");
  }
  H5 ds(H5Dcreate2(file, name, type, space, H5P_DEFAULT, plist, H5P_DEFAULT), H5Dclose);
  if (!ds.ok()) throw input_error(fname, name, "cannot create dataset");
  if (any) check(H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data), fname, name);
}

// Fixed-length, null-padded strings in a checksummed chunk: variable-length strings live in
// HDF5's global heap, which has no checksum, and HDF5 1.10 crashes reading a corrupted one.
void write_strings(hid_t file, const std::string& fname, const char* name, const std::vector<std::string>& values) {
  std::size_t width = 1;
  for (const auto& v : values) width = std::max(width, v.size());
  H5 type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, width);
  H5Tset_strpad(type, H5T_STR_NULLPAD);
  H5Tset_cset(type, H5T_CSET_UTF8);
  hsize_t n = values.size();
  H5 space(H5Screate_simple(1, &n, nullptr), H5Sclose);
  H5 plist(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
  if (!nn::add_checksum(plist, 1, &n)) throw input_error(fname, name, "cannot set up the checksum filter");
  H5 ds(H5Dcreate2(file, name, type, space, H5P_DEFAULT, plist, H5P_DEFAULT), H5Dclose);
  if (!ds.ok()) throw input_error(fname, name, "cannot create dataset");
  std::string packed(width * values.size(), '\0');
  for (std::size_t i = 0; i < values.size(); ++i) std::copy(values[i].begin(), values[i].end(), packed.begin() + i * width);
  if (n) check(H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, packed.data()), fname, name);
}

// Fixed-length: the text then sits in the checksummed object header, not the global heap.
void write_attr(hid_t obj, const std::string& fname, const char* name, const std::string& value) {
  H5 type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, std::max<std::size_t>(value.size(), 1));
  H5Tset_strpad(type, H5T_STR_NULLPAD);
  H5Tset_cset(type, H5T_CSET_UTF8);
  H5 space(H5Screate(H5S_SCALAR), H5Sclose);
  H5 attr(H5Acreate2(obj, name, type, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  const std::string padded = value.empty() ? std::string(1, '\0') : value;
  check(H5Awrite(attr, type, padded.data()), fname, std::string("attribute ") + name);
}

void write_attr_int(hid_t obj, const std::string& fname, const char* name, long long value) {
  H5 space(H5Screate(H5S_SCALAR), H5Sclose);
  H5 attr(H5Acreate2(obj, name, H5T_NATIVE_LLONG, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  check(H5Awrite(attr, H5T_NATIVE_LLONG, &value), fname, std::string("attribute ") + name);
}

std::string read_attr(hid_t obj, const std::string& fname, const char* name) {
  if (H5Aexists(obj, name) <= 0) throw input_error(fname, std::string("attribute ") + name, "missing");
  H5 attr(H5Aopen(obj, name, H5P_DEFAULT), H5Aclose);
  H5 ftype(H5Aget_type(attr), H5Tclose);
  if (H5Tget_class(ftype) != H5T_STRING) throw input_error(fname, std::string("attribute ") + name, "expected a string");
  if (H5Tis_variable_str(ftype) > 0) {
    H5 type(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(type, H5T_VARIABLE);
    H5Tset_cset(type, H5Tget_cset(ftype));
    char* p = nullptr;
    if (H5Aread(attr, type, &p) < 0) throw input_error(fname, std::string("attribute ") + name, "cannot be read");
    std::string s = p ? p : "";
    H5free_memory(p);
    return s;
  }
  const std::size_t size = H5Tget_size(ftype);
  std::string s(size, '\0');
  H5 type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, size);
  H5Tset_strpad(type, H5T_STR_NULLPAD);  // all `size` bytes are text (a null-terminated read would drop the last)
  H5Tset_cset(type, H5Tget_cset(ftype));
  if (H5Aread(attr, type, s.data()) < 0) throw input_error(fname, std::string("attribute ") + name, "cannot be read");
  s.resize(std::strlen(s.c_str()));
  return s;
}

// Opens a dataset and checks its rank and (where given, >= 0) its dimensions.
hid_t open_checked(hid_t file, const std::string& fname, const char* name, const std::vector<long long>& expect,
                   std::vector<hsize_t>& dims) {
  if (H5Lexists(file, name, H5P_DEFAULT) <= 0) throw input_error(fname, std::string("dataset ") + name, "missing");
  hid_t ds = H5Dopen2(file, name, H5P_DEFAULT);
  if (ds < 0) throw input_error(fname, std::string("dataset ") + name, "cannot be opened");
  H5 space(H5Dget_space(ds), H5Sclose);
  const int rank = H5Sget_simple_extent_ndims(space);
  if (rank != static_cast<int>(expect.size())) {
    H5Dclose(ds);
    throw input_error(fname, std::string("dataset ") + name,
                      "expected rank " + std::to_string(expect.size()) + ", got " + std::to_string(rank));
  }
  dims.assign(rank, 0);
  H5Sget_simple_extent_dims(space, dims.data(), nullptr);
  for (int i = 0; i < rank; ++i) {
    if (expect[i] >= 0 && static_cast<long long>(dims[i]) != expect[i]) {
      std::string got, want;
      for (int k = 0; k < rank; ++k) {
        got += (k ? " x " : "") + std::to_string(dims[k]);
        want += (k ? " x " : "") + (expect[k] >= 0 ? std::to_string(expect[k]) : std::string("*"));
      }
      H5Dclose(ds);
      throw input_error(fname, std::string("dataset ") + name, "shape " + got + ", expected " + want);
    }
  }
  return ds;
}

void read_into(hid_t file, const std::string& fname, const char* name, hid_t mem_type, const std::vector<long long>& expect,
               void* out) {
  std::vector<hsize_t> dims;
  H5 ds(open_checked(file, fname, name, expect, dims), H5Dclose);
  if (H5Dread(ds, mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, out) < 0)
    throw input_error(fname, std::string("dataset ") + name, "cannot be read (wrong type?)");
}

std::vector<std::string> read_strings(hid_t file, const std::string& fname, const char* name, long long expect) {
  std::vector<hsize_t> dims;
  H5 ds(open_checked(file, fname, name, {expect}, dims), H5Dclose);
  H5 ftype(H5Dget_type(ds), H5Tclose);
  if (H5Tget_class(ftype) != H5T_STRING) throw input_error(fname, std::string("dataset ") + name, "expected strings");
  if (H5Tis_variable_str(ftype) <= 0) {  // fixed-length (files since issue 13)
    const std::size_t width = H5Tget_size(ftype);
    if (width == 0 || width > (1u << 20)) throw input_error(fname, std::string("dataset ") + name, "implausible string width");
    std::string packed(width * dims[0], '\0');
    if (dims[0] && H5Dread(ds, ftype, H5S_ALL, H5S_ALL, H5P_DEFAULT, packed.data()) < 0)
      throw input_error(fname, std::string("dataset ") + name, "cannot be read as strings (corrupt file?)");
    std::vector<std::string> out;
    for (std::size_t i = 0; i < dims[0]; ++i) {
      std::string v = packed.substr(i * width, width);
      v.resize(std::strlen(v.c_str()));
      out.push_back(std::move(v));
    }
    return out;
  }
  H5 type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, H5T_VARIABLE);
  H5Tset_cset(type, H5Tget_cset(ftype));
  std::vector<char*> ptrs(dims[0], nullptr);
  if (dims[0] && H5Dread(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, ptrs.data()) < 0)
    throw input_error(fname, std::string("dataset ") + name, "cannot be read as strings");
  std::vector<std::string> out;
  for (char* p : ptrs) {
    out.emplace_back(p ? p : "");
    H5free_memory(p);
  }
  return out;
}

std::vector<std::string> json_strings(const std::string& text, const std::string& fname, const std::string& field) {
  try {
    return nlohmann::json::parse(text).get<std::vector<std::string>>();
  } catch (const nlohmann::json::exception&) {
    throw input_error(fname, field, "expected a JSON list of strings");
  }
}

}  // namespace

int Dataset::channel_index(const std::string& name) const {
  auto it = std::find(channels.begin(), channels.end(), name);
  if (it == channels.end()) throw Error("dataset: channel '" + name + "': missing");
  return static_cast<int>(it - channels.begin());
}

pgm::ChannelView Dataset::view(int n) const {
  pgm::ChannelView v;
  v.names = &channels;
  v.data = pgm.image(n);
  v.rows = rows();
  v.cols = cols();
  v.mask = mask.image(n);
  return v;
}

pgm::PolarGridMap Dataset::frame_pgm(int n) const {
  std::vector<std::string> names = channels;
  names.push_back("intensity");
  names.push_back("mask");
  pgm::PolarGridMap out(layout, names);
  const std::size_t plane = static_cast<std::size_t>(rows()) * cols();
  for (int c = 0; c < static_cast<int>(channels.size()); ++c)
    std::copy(pgm.channel(n, c), pgm.channel(n, c) + plane, out.channel(c));
  std::copy(target.image(n), target.image(n) + plane, out.channel("intensity"));
  std::copy(mask.image(n), mask.image(n) + plane, out.channel("mask"));
  if (!point_index.empty())
    for (std::size_t i = 0; i < plane; ++i) out.point_index()[i] = point_index[n * plane + i];
  return out;
}

void Dataset::append(const pgm::PolarGridMap& map, const std::string& frame_id, const std::string& row_mode) {
  if (frames.empty()) {
    layout = map.layout();
  } else if (!(map.layout() == layout)) {
    throw Error("dataset: frame " + frame_id + ": beam layout differs from the first frame's");
  }
  if (channels.empty()) throw Error("dataset: channels: set the /pgm channel names before appending frames");
  const int n = size(), C = static_cast<int>(channels.size()), H = map.rows(), W = map.cols();
  if (n > 0 && (H != rows() || W != cols())) throw Error("dataset: frame " + frame_id + ": grid size differs");
  // Grow by copying (imports are small; this keeps the tensors contiguous for training).
  auto grow = [&](nn::Tensor& t, int c) {
    nn::Tensor bigger(n + 1, c, H, W);
    if (n > 0) std::copy(t.begin(), t.end(), bigger.begin());
    t = std::move(bigger);
  };
  grow(pgm, C);
  grow(target, 1);
  grow(mask, 1);
  const std::size_t plane = static_cast<std::size_t>(H) * W;
  for (int c = 0; c < C; ++c) {
    const float* src = map.channel(channels[c]);
    std::copy(src, src + plane, pgm.channel(n, c));
  }
  const float* intensity = map.channel("intensity");
  const float* m = map.channel("mask");
  std::copy(intensity, intensity + plane, target.image(n));
  std::copy(m, m + plane, mask.image(n));
  for (std::size_t i = 0; i < plane; ++i) point_index.push_back(static_cast<std::int32_t>(map.point_index()[i]));
  frames.push_back(frame_id);
  row_modes.push_back(row_mode);
}

nn::Tensor encode_inputs(const Dataset& d, const pgm::EncoderConfig& config, const std::string& where) {
  std::vector<std::string> available = d.channels;
  available.push_back("intensity");  // the target lives in /target
  config.check_channels(available, where);
  if (config.target != "intensity")
    throw input_error(where, "encoder target '" + config.target + "'", "datasets carry only intensity as target");
  nn::Tensor out(d.size(), config.input_channels(), d.rows(), d.cols());
  for (int n = 0; n < d.size(); ++n) pgm::encode_input(d.view(n), config, out, n);
  return out;
}

void write_dataset(const fs::path& path, const Dataset& d) {
  quiet();
  const std::string fname = path.string();
  const int N = d.size(), C = static_cast<int>(d.channels.size()), H = d.rows(), W = d.cols();
  if (d.pgm.shape().c != C) throw input_error(fname, "/pgm", "channel count differs from the channel names");
  if (static_cast<int>(d.frames.size()) != N || static_cast<int>(d.row_modes.size()) != N)
    throw input_error(fname, "/frames", "one frame id and row mode per frame expected");
  {
    // Built in memory, written by save_memory_file: a full disk is an Error, not a crash in
    // HDF5's exit handler (nn/h5_memory_file.h).
    H5 file(nn::create_memory_file(path), H5Fclose);
    if (!file.ok()) throw input_error(fname, "file", "cannot be created");
    const hsize_t n = N, c = C, h = H, w = W;
    write_array(file, fname, "/pgm", H5T_NATIVE_FLOAT, {n, c, h, w}, d.pgm.data());
    write_array(file, fname, "/target", H5T_NATIVE_FLOAT, {n, 1, h, w}, d.target.data());
    std::vector<std::uint8_t> mask(d.mask.numel());
    for (std::size_t i = 0; i < mask.size(); ++i) mask[i] = d.mask.data()[i] > 0 ? 1 : 0;
    write_array(file, fname, "/mask", H5T_NATIVE_UINT8, {n, 1, h, w}, mask.data());
    if (!d.point_index.empty()) {
      if (d.point_index.size() != static_cast<std::size_t>(N) * H * W)
        throw input_error(fname, "/point_index", "size differs from N x H x W");
      write_array(file, fname, "/point_index", H5T_NATIVE_INT32, {n, h, w}, d.point_index.data());
    }
    write_strings(file, fname, "/frames", d.frames);
    write_strings(file, fname, "/sources", d.sources);
    H5 root(H5Gopen2(file, "/", H5P_DEFAULT), H5Gclose);
    write_attr(root, fname, "format", "lidarsim-dataset");
    write_attr_int(root, fname, "version", 1);
    write_attr(root, fname, "channels", nlohmann::json(d.channels).dump());
    write_attr(root, fname, "beam_layout", d.layout.to_json());
    write_attr(root, fname, "source_format", d.source_format);
    write_attr(root, fname, "row_modes", nlohmann::json(d.row_modes).dump());
    write_attr(root, fname, "target_channel", "intensity");
    nn::save_memory_file(file.release(), path);
  }
}

Dataset read_dataset(const fs::path& path, const std::vector<std::string>& required_channels) {
  quiet();
  const std::string fname = path.string();
  if (!fs::is_regular_file(path)) throw input_error(fname, "file", "not found");
  if (H5Fis_hdf5(path.c_str()) <= 0) throw input_error(fname, "file", "not an HDF5 file");
  H5 file(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!file.ok()) throw input_error(fname, "file", "cannot be opened as HDF5");
  H5 root(H5Gopen2(file, "/", H5P_DEFAULT), H5Gclose);
  Dataset d;
  if (read_attr(root, fname, "format") != "lidarsim-dataset")
    throw input_error(fname, "attribute format", "expected 'lidarsim-dataset'");
  d.channels = json_strings(read_attr(root, fname, "channels"), fname, "attribute channels");
  d.layout = pgm::BeamLayout::from_json(read_attr(root, fname, "beam_layout"), fname + ": attribute beam_layout");
  d.source_format = read_attr(root, fname, "source_format");
  for (const auto& c : required_channels) {
    if (c == "mask" || c == "intensity") continue;  // /mask and /target
    if (std::find(d.channels.begin(), d.channels.end(), c) == d.channels.end()) {
      std::string have;
      for (const auto& a : d.channels) have += (have.empty() ? "" : ", ") + a;
      throw input_error(fname, "/pgm channel '" + c + "'", "missing (the file has: " + have + ")");
    }
  }
  std::vector<hsize_t> dims;
  { H5 ds(open_checked(file, fname, "/pgm", {-1, static_cast<long long>(d.channels.size()), d.layout.rows(), d.layout.columns}, dims), H5Dclose); }
  const int N = static_cast<int>(dims[0]), C = static_cast<int>(dims[1]), H = static_cast<int>(dims[2]),
            W = static_cast<int>(dims[3]);
  d.pgm.resize({N, C, H, W});
  d.target.resize({N, 1, H, W});
  d.mask.resize({N, 1, H, W});
  if (N > 0) {
    read_into(file, fname, "/pgm", H5T_NATIVE_FLOAT, {N, C, H, W}, d.pgm.data());
    read_into(file, fname, "/target", H5T_NATIVE_FLOAT, {N, 1, H, W}, d.target.data());
    std::vector<std::uint8_t> mask(static_cast<std::size_t>(N) * H * W);
    read_into(file, fname, "/mask", H5T_NATIVE_UINT8, {N, 1, H, W}, mask.data());
    for (std::size_t i = 0; i < mask.size(); ++i) d.mask.data()[i] = mask[i] ? 1.f : 0.f;
  } else {
    std::vector<hsize_t> unused;
    H5 t(open_checked(file, fname, "/target", {0, 1, H, W}, unused), H5Dclose);
    H5 m(open_checked(file, fname, "/mask", {0, 1, H, W}, unused), H5Dclose);
  }
  if (H5Lexists(file, "/point_index", H5P_DEFAULT) > 0 && N > 0) {
    d.point_index.resize(static_cast<std::size_t>(N) * H * W);
    read_into(file, fname, "/point_index", H5T_NATIVE_INT32, {N, H, W}, d.point_index.data());
  }
  d.frames = read_strings(file, fname, "/frames", N);
  d.sources = read_strings(file, fname, "/sources", -1);
  d.row_modes = json_strings(read_attr(root, fname, "row_modes"), fname, "attribute row_modes");
  if (static_cast<int>(d.row_modes.size()) != N)
    throw input_error(fname, "attribute row_modes", "expected one entry per frame (" + std::to_string(N) + ")");
  for (std::size_t i = 0; i < d.pgm.numel(); ++i)
    if (!std::isfinite(d.pgm.data()[i])) throw input_error(fname, "/pgm", "contains NaN or Inf");
  for (std::size_t i = 0; i < d.target.numel(); ++i)
    if (!std::isfinite(d.target.data()[i])) throw input_error(fname, "/target", "contains NaN or Inf");
  return d;
}

}  // namespace lidarsim::data
