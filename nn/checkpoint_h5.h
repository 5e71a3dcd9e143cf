#pragma once
// The HDF5 file a checkpoint is written to and read from (nn/checkpoint.cpp only): a Writer that
// builds the file in memory with deterministic bytes (no timestamps, fixed property lists,
// Fletcher-32 on every numeric dataset, fixed-length strings) and a Reader whose every lookup
// checks existence first, so a missing or malformed object is one lidarsim::Error naming it, never
// an HDF5 stack trace or a crash. What goes where in the file is checkpoint.cpp's business.
#include <hdf5.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "common/error.h"
#include "nn/checkpoint_image.h"
#include "nn/h5_memory_file.h"
#include "nn/params.h"

namespace lidarsim::nn::checkpoint_h5 {

// HDF5 prints its own error stack to stderr by default; we turn every failure into one
// lidarsim::Error instead. Called at each entry point (the setting is per thread).
inline void silence_hdf5() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

// Owns one HDF5 identifier and closes it with the matching H5?close.
class Handle {
 public:
  Handle() = default;
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  Handle(Handle&& o) noexcept : id_(o.id_), close_(o.close_) { o.id_ = H5I_INVALID_HID; }
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      id_ = o.id_;
      close_ = o.close_;
      o.id_ = H5I_INVALID_HID;
    }
    return *this;
  }
  ~Handle() { reset(); }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  hid_t release() {
    const hid_t id = id_;
    id_ = H5I_INVALID_HID;
    return id;
  }
  // Closes now and reports whether that worked (the file close flushes, so it can fail).
  bool close() {
    if (id_ < 0) return true;
    const herr_t rc = close_(id_);
    id_ = H5I_INVALID_HID;
    return rc >= 0;
  }

 private:
  void reset() {
    if (id_ >= 0 && close_) close_(id_);
    id_ = H5I_INVALID_HID;
  }
  hid_t id_ = H5I_INVALID_HID;
  herr_t (*close_)(hid_t) = nullptr;
};

// "enc0.conv1/weight" under "params" -> "params/enc0.conv1/weight".
inline std::string join(const std::string& a, const std::string& b) { return a.empty() ? b : a + "/" + b; }

// The dataset shape a PyTorch user expects: biases are 1-D [out], everything else 4-D.
inline std::vector<hsize_t> param_dims(const ParamInfo& info) {
  const Shape& s = info.shape;
  if (!info.decays && s.c == 1 && s.h == 1 && s.w == 1) return {static_cast<hsize_t>(s.n)};
  return {static_cast<hsize_t>(s.n), static_cast<hsize_t>(s.c), static_cast<hsize_t>(s.h),
          static_cast<hsize_t>(s.w)};
}

inline std::string dims_str(const std::vector<hsize_t>& dims) {
  std::string out = "[";
  for (std::size_t i = 0; i < dims.size(); ++i) out += (i ? ", " : "") + std::to_string(dims[i]);
  return out + "]";
}

// ---------------------------------------------------------------------------------------------
// Writing. Every object is created without timestamps and with fixed property lists, so two
// saves of the same state are byte-identical files. The file is built in memory and written by
// save_memory_file (nn/h5_memory_file.h): a full disk is one Error, never a crash in HDF5's exit
// handler. Integrity: every numeric dataset carries a Fletcher-32 checksum, strings are
// fixed-length (so they live in the checksummed object headers, not the unsummed global heap).

class Writer {
 public:
  explicit Writer(const std::filesystem::path& final_path) : path_(final_path), name_(final_path.string()) {
    gcpl_ = Handle(H5Pcreate(H5P_GROUP_CREATE), H5Pclose);
    dcpl_ = Handle(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
    if (!gcpl_.valid() || !dcpl_.valid() || H5Pset_obj_track_times(gcpl_.get(), false) < 0 || !keep_compact(gcpl_.get()) ||
        H5Pset_obj_track_times(dcpl_.get(), false) < 0)
      fail("file", "cannot set up HDF5 property lists");
    file_ = Handle(create_memory_file(final_path), H5Fclose);
    if (!file_.valid()) fail("file", "cannot create the HDF5 file in memory");
  }

  // Creates every missing group along `path` (without timestamps) and returns the last one.
  Handle group(const std::string& path) {
    Handle g(H5Gopen2(file_.get(), "/", H5P_DEFAULT), H5Gclose);
    std::string so_far;
    std::size_t start = 0;
    while (start < path.size()) {
      const std::size_t slash = path.find('/', start);
      const std::string part = path.substr(start, slash == std::string::npos ? std::string::npos : slash - start);
      so_far = join(so_far, part);
      const htri_t exists = H5Lexists(g.get(), part.c_str(), H5P_DEFAULT);
      Handle next(exists > 0 ? H5Gopen2(g.get(), part.c_str(), H5P_DEFAULT)
                             : H5Gcreate2(g.get(), part.c_str(), H5P_DEFAULT, gcpl_.get(), H5P_DEFAULT),
                  H5Gclose);
      if (!next.valid()) fail(so_far, "cannot create group");
      g = std::move(next);
      if (slash == std::string::npos) break;
      start = slash + 1;
    }
    return g;
  }

  void floats(const std::string& path, const std::vector<hsize_t>& dims, const float* data) {
    const std::size_t slash = path.rfind('/');
    Handle parent = group(path.substr(0, slash));
    const std::string leaf = path.substr(slash + 1);
    Handle space(H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr), H5Sclose);
    Handle dcpl(H5Pcopy(dcpl_.get()), H5Pclose);
    if (!dcpl.valid() || !add_checksum(dcpl.get(), static_cast<int>(dims.size()), dims.data()))
      fail(path, "cannot set up the checksum filter");
    Handle set(H5Dcreate2(parent.get(), leaf.c_str(), H5T_IEEE_F32LE, space.get(), H5P_DEFAULT, dcpl.get(),
                          H5P_DEFAULT),
               H5Dclose);
    if (!space.valid() || !set.valid() ||
        H5Dwrite(set.get(), H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
      fail(path, "cannot write dataset");
  }

  void string_dataset(const std::string& path, const std::string& value) {
    const std::size_t slash = path.rfind('/');
    Handle parent = group(path.substr(0, slash));
    Handle type = utf8_type(value.size());
    // One element, chunked, so the Fletcher-32 filter covers the text too.
    const hsize_t one = 1;
    Handle space(H5Screate_simple(1, &one, nullptr), H5Sclose);
    Handle dcpl(H5Pcopy(dcpl_.get()), H5Pclose);
    if (!dcpl.valid() || !add_checksum(dcpl.get(), 1, &one)) fail(path, "cannot set up the checksum filter");
    Handle set(H5Dcreate2(parent.get(), path.substr(slash + 1).c_str(), type.get(), space.get(), H5P_DEFAULT,
                          dcpl.get(), H5P_DEFAULT),
               H5Dclose);
    const std::string padded = value.empty() ? std::string(1, '\0') : value;
    if (!set.valid() || H5Dwrite(set.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, padded.data()) < 0)
      fail(path, "cannot write dataset");
  }

  void attr(hid_t obj, const std::string& where, const std::string& name, const std::string& value) {
    Handle type = utf8_type(value.size());
    const std::string padded = value.empty() ? std::string(1, '\0') : value;
    write_attr(obj, where, name, type.get(), type.get(), padded.data());
  }
  void attr(hid_t obj, const std::string& where, const std::string& name, std::int64_t value) {
    write_attr(obj, where, name, H5T_STD_I64LE, H5T_NATIVE_INT64, &value);
  }
  void attr(hid_t obj, const std::string& where, const std::string& name, double value) {
    write_attr(obj, where, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &value);
  }
  // A float setting as the double nearest its shortest decimal form: h5py shows 0.9, not
  // 0.8999999761581421, and casting back to float gives the same float.
  void attr(hid_t obj, const std::string& where, const std::string& name, float value) {
    char buf[32];
    const auto res = std::to_chars(buf, buf + sizeof buf, value);
    attr(obj, where, name, std::strtod(std::string(buf, res.ptr).c_str(), nullptr));
  }

  // Builds the file image and writes it atomically (temporary + rename).
  void close() {
    gcpl_.close();
    dcpl_.close();
    save_memory_file(file_.release(), path_);
  }

  [[noreturn]] void fail(const std::string& field, const std::string& message) const {
    throw input_error(name_, field, message);
  }

 private:
  // Fixed-length UTF-8 of exactly the text's bytes, null-padded (h5py reads it as bytes).
  static Handle utf8_type(std::size_t length) {
    Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(type.get(), std::max<std::size_t>(length, 1));
    H5Tset_strpad(type.get(), H5T_STR_NULLPAD);
    H5Tset_cset(type.get(), H5T_CSET_UTF8);
    return type;
  }
  void write_attr(hid_t obj, const std::string& where, const std::string& name, hid_t file_type, hid_t mem_type,
                  const void* data) {
    Handle space(H5Screate(H5S_SCALAR), H5Sclose);
    Handle a(H5Acreate2(obj, name.c_str(), file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!a.valid() || H5Awrite(a.get(), mem_type, data) < 0) fail(join(where, name), "cannot write attribute");
  }

  std::filesystem::path path_;
  std::string name_;
  Handle file_, gcpl_, dcpl_;
};

// ---------------------------------------------------------------------------------------------
// Reading: every lookup checks existence first, so a missing or malformed object becomes an
// Error naming it, never an HDF5 stack trace or a crash.

class Reader {
 public:
  explicit Reader(const std::filesystem::path& path) : name_(path.string()) {
    if (!std::filesystem::exists(path)) throw Error(name_ + ": cannot open: no such file");
    const Handle fapl = access_list();
    opened(H5Fopen(path.c_str(), H5F_ACC_RDONLY, fapl.get()));
  }
  // The same checks on a file's bytes in memory (nn/h5_memory_file.h).
  explicit Reader(const MemoryImage& image) : name_(image.name.string()) {
    const Handle fapl = access_list();
    opened(open_memory_image(image, fapl.get()));
  }

  bool exists(const std::string& path) const {
    // H5Lexists needs every parent to exist, so walk the path one component at a time.
    std::string so_far;
    std::size_t start = 0;
    while (true) {
      const std::size_t slash = path.find('/', start);
      so_far = path.substr(0, slash);
      if (H5Lexists(file_.get(), so_far.c_str(), H5P_DEFAULT) <= 0) return false;
      if (slash == std::string::npos) return true;
      start = slash + 1;
    }
  }

  Handle object(const std::string& path) const {
    if (!exists(path)) fail(path, "missing");
    Handle obj(H5Oopen(file_.get(), path.c_str(), H5P_DEFAULT), H5Oclose);
    if (!obj.valid()) fail(path, "cannot open (corrupt file?)");
    return obj;
  }

  // A float dataset of exactly `dims`, read as float32; NaN/Inf are an error.
  std::vector<float> floats(const std::string& path, const std::vector<hsize_t>& dims) const {
    Handle set = dataset(path);
    Handle type(H5Dget_type(set.get()), H5Tclose);
    if (!type.valid() || H5Tget_class(type.get()) != H5T_FLOAT)
      fail(path, "expected a floating-point dataset");
    Handle space(H5Dget_space(set.get()), H5Sclose);
    const int rank = space.valid() ? H5Sget_simple_extent_ndims(space.get()) : -1;
    if (rank < 0) fail(path, "cannot read the shape (corrupt file?)");
    std::vector<hsize_t> have(static_cast<std::size_t>(rank));
    H5Sget_simple_extent_dims(space.get(), have.data(), nullptr);
    if (have != dims) fail(path, "shape " + dims_str(have) + " does not match the model's " + dims_str(dims));
    std::size_t count = 1;
    for (hsize_t d : dims) count *= d;
    std::vector<float> out(count);
    if (H5Dread(set.get(), H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()) < 0)
      fail(path, "cannot read the values (truncated or corrupt file?)");
    for (std::size_t i = 0; i < count; ++i)
      if (!std::isfinite(out[i])) fail(path, "value " + std::to_string(i) + " is not finite");
    return out;
  }

  std::string string_dataset(const std::string& path) const {
    Handle set = dataset(path);
    Handle space(H5Dget_space(set.get()), H5Sclose);
    if (!space.valid() || H5Sget_simple_extent_npoints(space.get()) != 1) fail(path, "expected one string");
    return read_string(path, set.get(), true);
  }

  bool has_attr(const std::string& obj, const std::string& name) const {
    return exists(obj) && H5Aexists_by_name(file_.get(), obj.c_str(), name.c_str(), H5P_DEFAULT) > 0;
  }

  std::int64_t int_attr(const std::string& obj, const std::string& name) const {
    Handle a = attribute(obj, name);
    Handle type(H5Aget_type(a.get()), H5Tclose);
    std::int64_t v = 0;
    if (H5Tget_class(type.get()) != H5T_INTEGER || H5Aread(a.get(), H5T_NATIVE_INT64, &v) < 0)
      fail(join(obj, name), "expected an integer attribute");
    return v;
  }

  double double_attr(const std::string& obj, const std::string& name) const {
    Handle a = attribute(obj, name);
    Handle type(H5Aget_type(a.get()), H5Tclose);
    const H5T_class_t cls = H5Tget_class(type.get());
    double v = 0;
    if ((cls != H5T_FLOAT && cls != H5T_INTEGER) || H5Aread(a.get(), H5T_NATIVE_DOUBLE, &v) < 0)
      fail(join(obj, name), "expected a number");
    if (!std::isfinite(v)) fail(join(obj, name), "expected a finite number");
    return v;
  }

  std::string string_attr(const std::string& obj, const std::string& name) const {
    Handle a = attribute(obj, name);
    return read_string(join(obj, name), a.get(), false);
  }

  // Names of all attributes of `obj`, in name order.
  std::vector<std::string> attr_names(const std::string& obj) const {
    Handle o = object(obj);
    std::vector<std::string> names;
    auto cb = [](hid_t, const char* name, const H5A_info_t*, void* data) -> herr_t {
      static_cast<std::vector<std::string>*>(data)->push_back(name);
      return 0;
    };
    if (H5Aiterate2(o.get(), H5_INDEX_NAME, H5_ITER_INC, nullptr, cb, &names) < 0)
      fail(obj, "cannot list attributes (corrupt file?)");
    return names;
  }

  // Paths (relative to `group`) of every dataset below it.
  std::vector<std::string> datasets_below(const std::string& group) const {
    Handle g = object(group);
    struct Ctx {
      hid_t group;
      std::vector<std::string> names;
    } ctx{g.get(), {}};
    auto cb = [](hid_t, const char* name, const H5L_info_t*, void* data) -> herr_t {
      auto* c = static_cast<Ctx*>(data);
      Handle obj(H5Oopen(c->group, name, H5P_DEFAULT), H5Oclose);
      if (obj.valid() && H5Iget_type(obj.get()) == H5I_DATASET) c->names.push_back(name);
      return 0;
    };
    if (H5Lvisit(g.get(), H5_INDEX_NAME, H5_ITER_INC, cb, &ctx) < 0)
      fail(group, "cannot list datasets (corrupt file?)");
    return ctx.names;
  }

  [[noreturn]] void fail(const std::string& field, const std::string& message) const {
    throw input_error(name_, field, message);
  }

 private:
  // STRONG: closing the file closes anything still open inside it.
  static Handle access_list() {
    Handle fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
    H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG);
    return fapl;
  }
  void opened(hid_t file) {
    file_ = Handle(file, H5Fclose);
    if (!file_.valid())
      throw Error(name_ + ": cannot open as an HDF5 checkpoint (truncated, corrupt or not HDF5)");
  }

  Handle dataset(const std::string& path) const {
    if (!exists(path)) fail(path, "missing dataset");
    Handle set(H5Dopen2(file_.get(), path.c_str(), H5P_DEFAULT), H5Dclose);
    if (!set.valid()) fail(path, "not a dataset or unreadable (corrupt file?)");
    return set;
  }

  Handle attribute(const std::string& obj, const std::string& name) const {
    if (!has_attr(obj, name)) fail(join(obj, name), "missing attribute");
    Handle a(H5Aopen_by_name(file_.get(), obj.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!a.valid()) fail(join(obj, name), "cannot open attribute (corrupt file?)");
    return a;
  }

  // Reads a scalar string (variable-length or fixed-size) from an attribute or a dataset.
  std::string read_string(const std::string& field, hid_t id, bool is_dataset) const {
    Handle type(is_dataset ? H5Dget_type(id) : H5Aget_type(id), H5Tclose);
    if (!type.valid() || H5Tget_class(type.get()) != H5T_STRING) fail(field, "expected a string");
    auto read = [&](hid_t mem, void* buf) {
      return is_dataset ? H5Dread(id, mem, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf) : H5Aread(id, mem, buf);
    };
    if (H5Tis_variable_str(type.get()) > 0) {
      Handle mem(H5Tcopy(H5T_C_S1), H5Tclose);
      H5Tset_size(mem.get(), H5T_VARIABLE);
      H5Tset_cset(mem.get(), H5Tget_cset(type.get()));
      char* ptr = nullptr;
      if (read(mem.get(), &ptr) < 0) fail(field, "cannot read string");
      std::string out = ptr ? ptr : "";
      H5free_memory(ptr);
      return out;
    }
    const std::size_t size = H5Tget_size(type.get());
    std::string out(size, '\0');
    if (read(type.get(), out.data()) < 0) fail(field, "cannot read string");
    out.resize(out.find('\0') == std::string::npos ? size : out.find('\0'));
    while (!out.empty() && out.back() == ' ') out.pop_back();  // H5T_STR_SPACEPAD
    return out;
  }

  std::string name_;
  Handle file_;
};

}  // namespace lidarsim::nn::checkpoint_h5
