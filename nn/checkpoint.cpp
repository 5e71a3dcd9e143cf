#include "nn/checkpoint.h"

#include <hdf5.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <vector>

#include "common/error.h"
#include "nn/checkpoint_image.h"
#include "nn/h5_memory_file.h"

namespace lidarsim::nn {
namespace {

// Format 1: one output, `unet.out_channels`. Format 2 (several outputs, or named heads): the output
// count is `unet.outputs` and `unet.out_channels` is left out, so builds that predate format 2
// (they read `unet.out_channels` and never read `format`) reject the file naming that attribute
// instead of loading a several-output model as a one-output one. A model format 1 describes is
// still written as format 1, byte for byte as before.
constexpr const char* kFormatPrefix = "lidarsim-checkpoint ";
constexpr int kNewestFormat = 2;

bool needs_format2(const UNetConfig& c) { return c.out_channels != 1 || !c.heads.empty(); }

// HDF5 prints its own error stack to stderr by default; we turn every failure into one
// lidarsim::Error instead. Called at each entry point (the setting is per thread).
void silence_hdf5() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

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
std::string join(const std::string& a, const std::string& b) { return a.empty() ? b : a + "/" + b; }

// The dataset shape a PyTorch user expects: biases are 1-D [out], everything else 4-D.
std::vector<hsize_t> param_dims(const ParamInfo& info) {
  const Shape& s = info.shape;
  if (!info.decays && s.c == 1 && s.h == 1 && s.w == 1) return {static_cast<hsize_t>(s.n)};
  return {static_cast<hsize_t>(s.n), static_cast<hsize_t>(s.c), static_cast<hsize_t>(s.h),
          static_cast<hsize_t>(s.w)};
}

std::string dims_str(const std::vector<hsize_t>& dims) {
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

bool reserved_attribute(const std::string& key) {
  return key == "format" || key.rfind("unet.", 0) == 0 || key.rfind("optimizer.", 0) == 0;
}

int positive_int_attr(const Reader& r, const std::string& name) {
  const std::int64_t v = r.int_attr("config", name);
  if (v < 1 || v > 1 << 20) r.fail("config/" + name, "expected a positive integer, got " + std::to_string(v));
  return static_cast<int>(v);
}

// No attribute: no per-row affine layer.
int row_affine_rows(const Reader& r) {
  return r.has_attr("config", "unet.row_affine_rows") ? positive_int_attr(r, "unet.row_affine_rows") : 0;
}

// The lookup base's config (nn/unet.h): absent = none.
LookupBaseConfig lookup_config(const Reader& r) {
  LookupBaseConfig c;
  if (!r.has_attr("config", "unet.lookup.classes")) return c;
  c.classes = positive_int_attr(r, "unet.lookup.classes");
  c.range_bins = positive_int_attr(r, "unet.lookup.range_bins");
  c.rows = positive_int_attr(r, "unet.lookup.rows");
  for (auto [name, field] : {std::pair{"unet.lookup.class_channel", &c.class_channel}, {"unet.lookup.range_channel", &c.range_channel}}) {
    const std::int64_t v = r.int_attr("config", name);
    if (v < 0 || v > 1 << 20) r.fail(std::string("config/") + name, "expected an integer >= 0, got " + std::to_string(v));
    *field = static_cast<int>(v);
  }
  c.bin_width = static_cast<float>(r.double_attr("config", "unet.lookup.bin_width"));
  if (!(c.bin_width > 0) || !std::isfinite(c.bin_width))
    r.fail("config/unet.lookup.bin_width", "expected a finite number > 0, got " + std::to_string(c.bin_width));
  return c;
}

}  // namespace

void save_checkpoint(const std::filesystem::path& path, const UNet& model, const Optimizer* optimizer,
                     const Checkpoint& meta) {
  silence_hdf5();
  const ParamArena& params = model.params();
  for (const auto& [key, value] : meta.attributes)
    if (reserved_attribute(key) || key.empty())
      throw input_error(path.string(), "config/" + key, "attribute name is reserved or empty");
  if (optimizer && (optimizer->m().size() != params.size() || optimizer->v().size() != params.size()))
    throw input_error(path.string(), "optimizer", "state does not match the model's " +
                                                      std::to_string(params.size()) + " parameters");

  {
    Writer w(path);
    {
      Handle config = w.group("config");
      const bool v2 = needs_format2(model.config());
      w.attr(config.get(), "config", "format", kFormatPrefix + std::to_string(v2 ? 2 : 1));
      w.attr(config.get(), "config", "unet.in_channels", std::int64_t{model.config().in_channels});
      if (!v2) w.attr(config.get(), "config", "unet.out_channels", std::int64_t{model.config().out_channels});
      if (v2) w.attr(config.get(), "config", "unet.outputs", std::int64_t{model.config().out_channels});
      if (!model.config().heads.empty()) w.attr(config.get(), "config", "unet.heads", heads_text(model.config().heads));
      w.attr(config.get(), "config", "unet.base", std::int64_t{model.config().base});
      w.attr(config.get(), "config", "unet.depth", std::int64_t{model.config().depth});
      // Only when present: a model without the layer writes no trace of it (read back as no layer).
      if (model.config().row_affine_rows > 0)
        w.attr(config.get(), "config", "unet.row_affine_rows", std::int64_t{model.config().row_affine_rows});
      if (const LookupBaseConfig& lk = model.config().lookup; lk.classes > 0) {
        w.attr(config.get(), "config", "unet.lookup.classes", std::int64_t{lk.classes});
        w.attr(config.get(), "config", "unet.lookup.class_channel", std::int64_t{lk.class_channel});
        w.attr(config.get(), "config", "unet.lookup.range_channel", std::int64_t{lk.range_channel});
        w.attr(config.get(), "config", "unet.lookup.range_bins", std::int64_t{lk.range_bins});
        w.attr(config.get(), "config", "unet.lookup.rows", std::int64_t{lk.rows});
        w.attr(config.get(), "config", "unet.lookup.bin_width", lk.bin_width);
      }
      if (optimizer) {
        const OptimizerConfig& oc = optimizer->config();
        w.attr(config.get(), "config", "optimizer.kind", oc.kind);
        w.attr(config.get(), "config", "optimizer.lr", oc.lr);
        w.attr(config.get(), "config", "optimizer.beta1", oc.beta1);
        w.attr(config.get(), "config", "optimizer.beta2", oc.beta2);
        w.attr(config.get(), "config", "optimizer.eps", oc.eps);
        w.attr(config.get(), "config", "optimizer.momentum", oc.momentum);
        w.attr(config.get(), "config", "optimizer.clip_norm", oc.clip_norm);
      }
      for (const auto& [key, value] : meta.attributes) w.attr(config.get(), "config", key, value);
    }
    for (const ParamInfo& info : params.infos())
      w.floats("params/" + info.name, param_dims(info), params.values() + info.offset);
    if (optimizer) {
      Handle opt = w.group("optimizer");
      w.attr(opt.get(), "optimizer", "kind", optimizer->config().kind);
      w.attr(opt.get(), "optimizer", "steps", optimizer->steps());
      for (const ParamInfo& info : params.infos()) {
        w.floats("optimizer/m/" + info.name, param_dims(info), optimizer->m().data() + info.offset);
        w.floats("optimizer/v/" + info.name, param_dims(info), optimizer->v().data() + info.offset);
      }
    }
    {
      Handle state = w.group("state");
      w.attr(state.get(), "state", "epoch", meta.state.epoch);
      w.attr(state.get(), "state", "step", meta.state.step);
    }
    w.string_dataset("state/rng", meta.state.rng);
    w.close();
  }
}

namespace {

// The file's format number: 1 without the attribute (files written by other tools, e.g. h5py);
// a newer format than this build knows is refused by name.
int format_of(const Reader& r) {
  if (!r.has_attr("config", "format")) return 1;
  const std::string text = r.string_attr("config", "format");
  const std::string prefix = kFormatPrefix;
  int v = 0;
  const char* end = text.data() + text.size();
  const bool number = text.rfind(prefix, 0) == 0 &&
                      std::from_chars(text.data() + prefix.size(), end, v).ptr == end && text.size() > prefix.size();
  if (!number) r.fail("config/format", "\"" + text + "\" is not a lidarsim checkpoint format");
  if (v < 1 || v > kNewestFormat)
    r.fail("config/format", "\"" + text + "\": this build reads formats 1 to " + std::to_string(kNewestFormat) +
                                (v > kNewestFormat ? " (written by a newer lidarsim: update to read it)" : ""));
  return v;
}

// The output channel count and heads: `unet.out_channels` in format 1, `unet.outputs` and the
// optional `unet.heads` in format 2.
void outputs_of(const Reader& r, UNetConfig& c) {
  const int format = format_of(r);
  c.out_channels = positive_int_attr(r, format == 1 ? "unet.out_channels" : "unet.outputs");
  c.heads.clear();
  if (r.has_attr("config", "unet.heads")) {
    if (format == 1) r.fail("config/unet.heads", "present in a format-1 checkpoint (format 2 carries heads)");
    const std::string text = r.string_attr("config", "unet.heads");
    try {
      c.heads = parse_heads(text, "value");
      check_heads(c.heads, c.out_channels, "value");
    } catch (const Error& e) {
      r.fail("config/unet.heads", e.what());
    }
  }
}

Checkpoint read_meta(const Reader& r) {
  Checkpoint meta;
  if (!r.exists("config")) r.fail("config", "missing group (not a lidarsim checkpoint?)");
  meta.unet.in_channels = positive_int_attr(r, "unet.in_channels");
  outputs_of(r, meta.unet);
  meta.unet.base = positive_int_attr(r, "unet.base");
  meta.unet.depth = positive_int_attr(r, "unet.depth");
  meta.unet.row_affine_rows = row_affine_rows(r);
  meta.unet.lookup = lookup_config(r);
  for (const std::string& name : r.attr_names("config"))
    if (!reserved_attribute(name)) meta.attributes[name] = r.string_attr("config", name);
  if (r.has_attr("config", "optimizer.kind")) {
    OptimizerConfig oc;
    oc.kind = r.string_attr("config", "optimizer.kind");
    oc.lr = static_cast<float>(r.double_attr("config", "optimizer.lr"));
    oc.beta1 = static_cast<float>(r.double_attr("config", "optimizer.beta1"));
    oc.beta2 = static_cast<float>(r.double_attr("config", "optimizer.beta2"));
    oc.eps = static_cast<float>(r.double_attr("config", "optimizer.eps"));
    oc.momentum = static_cast<float>(r.double_attr("config", "optimizer.momentum"));
    oc.clip_norm = static_cast<float>(r.double_attr("config", "optimizer.clip_norm"));
    meta.optimizer = oc;
  }
  meta.state.epoch = r.int_attr("state", "epoch");
  meta.state.step = r.int_attr("state", "step");
  meta.state.rng = r.string_dataset("state/rng");
  return meta;
}

void load(const Reader& r, UNet& model, Optimizer* optimizer) {
  const UNetConfig& want = model.config();
  UNetConfig have_outputs;
  outputs_of(r, have_outputs);
  if (have_outputs.out_channels != want.out_channels)
    r.fail(format_of(r) == 1 ? "config/unet.out_channels" : "config/unet.outputs",
           "checkpoint has " + std::to_string(have_outputs.out_channels) + ", the model expects " +
               std::to_string(want.out_channels));
  if (have_outputs.heads != want.heads)
    r.fail("config/unet.heads", "checkpoint has \"" + heads_text(have_outputs.heads) + "\", the model expects \"" +
                                    heads_text(want.heads) + "\"");
  const std::pair<const char*, int> fields[] = {{"unet.in_channels", want.in_channels},
                                                {"unet.base", want.base},
                                                {"unet.depth", want.depth}};
  for (const auto& [name, value] : fields) {
    const std::int64_t have = r.int_attr("config", name);
    if (have != value)
      r.fail(std::string("config/") + name,
             "checkpoint has " + std::to_string(have) + ", the model expects " + std::to_string(value));
  }
  if (const int have = row_affine_rows(r); have != want.row_affine_rows)
    r.fail("config/unet.row_affine_rows", "checkpoint has " + std::to_string(have) + " (0: no per-row affine layer), the model expects " +
                                              std::to_string(want.row_affine_rows));
  if (!(lookup_config(r) == want.lookup))
    r.fail("config/unet.lookup", want.lookup.classes > 0 ? "the lookup base's settings differ from the model's (or it has none)"
                                                         : "checkpoint has a lookup base, the model has none");

  // Validate and read everything first; copy into the model only when all of it is good.
  ParamArena& params = model.params();
  const std::vector<ParamInfo>& infos = params.infos();
  std::vector<std::vector<float>> values, m, v;
  for (const ParamInfo& info : infos) values.push_back(r.floats("params/" + info.name, param_dims(info)));
  for (const std::string& name : r.datasets_below("params"))
    if (params.find(name) < 0) r.fail("params/" + name, "not a parameter of this model");

  std::int64_t steps = 0;
  if (optimizer) {
    if (!r.exists("optimizer")) r.fail("optimizer", "missing group (checkpoint saved without an optimizer)");
    const std::string kind = r.string_attr("optimizer", "kind");
    if (kind != optimizer->config().kind)
      r.fail("optimizer/kind", "checkpoint has \"" + kind + "\", the optimizer is \"" + optimizer->config().kind + "\"");
    steps = r.int_attr("optimizer", "steps");
    if (steps < 0) r.fail("optimizer/steps", "expected >= 0, got " + std::to_string(steps));
    if (optimizer->m().size() != params.size() || optimizer->v().size() != params.size())
      r.fail("optimizer", "the optimizer's state size does not match the model");
    for (const ParamInfo& info : infos) {
      m.push_back(r.floats("optimizer/m/" + info.name, param_dims(info)));
      v.push_back(r.floats("optimizer/v/" + info.name, param_dims(info)));
    }
  }

  for (std::size_t i = 0; i < infos.size(); ++i)
    std::copy(values[i].begin(), values[i].end(), params.values() + infos[i].offset);
  if (optimizer) {
    for (std::size_t i = 0; i < infos.size(); ++i) {
      std::copy(m[i].begin(), m[i].end(), optimizer->m().begin() + static_cast<std::ptrdiff_t>(infos[i].offset));
      std::copy(v[i].begin(), v[i].end(), optimizer->v().begin() + static_cast<std::ptrdiff_t>(infos[i].offset));
    }
    optimizer->set_steps(steps);
  }
}

}  // namespace

Checkpoint read_checkpoint_meta(const std::filesystem::path& path) {
  silence_hdf5();
  return read_meta(Reader(path));
}

Checkpoint read_checkpoint_meta(const MemoryImage& image) {
  silence_hdf5();
  return read_meta(Reader(image));
}

void load_checkpoint(const std::filesystem::path& path, UNet& model, Optimizer* optimizer) {
  silence_hdf5();
  load(Reader(path), model, optimizer);
}

void load_checkpoint(const MemoryImage& image, UNet& model, Optimizer* optimizer) {
  silence_hdf5();
  load(Reader(image), model, optimizer);
}

}  // namespace lidarsim::nn
