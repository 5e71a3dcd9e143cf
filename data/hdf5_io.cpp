#include "data/hdf5_io.h"

#include <cstring>

#include <algorithm>

#include "common/error.h"
#include "nn/h5_memory_file.h"

namespace lidarsim::data::h5 {

void quiet() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

void check(herr_t status, const std::string& file, const std::string& what) {
  if (status < 0) throw input_error(file, what, "HDF5 write failed");
}

// Fixed-length: the text then sits in the checksummed object header, not in the global heap
// (no checksum; HDF5 1.10 crashes reading a corrupted variable-length string there).
void write_attr(hid_t obj, const std::string& fname, const char* name, const std::string& value) {
  Id type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, std::max<std::size_t>(value.size(), 1));
  H5Tset_strpad(type, H5T_STR_NULLPAD);
  H5Tset_cset(type, H5T_CSET_UTF8);
  Id space(H5Screate(H5S_SCALAR), H5Sclose);
  Id attr(H5Acreate2(obj, name, type, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  if (!attr.ok()) throw input_error(fname, std::string("attribute ") + name, "cannot be created");
  const std::string padded = value.empty() ? std::string(1, '\0') : value;
  check(H5Awrite(attr, type, padded.data()), fname, std::string("attribute ") + name);
}

void write_attr_int(hid_t obj, const std::string& fname, const char* name, long long value) {
  Id space(H5Screate(H5S_SCALAR), H5Sclose);
  Id attr(H5Acreate2(obj, name, H5T_NATIVE_LLONG, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  check(H5Awrite(attr, H5T_NATIVE_LLONG, &value), fname, std::string("attribute ") + name);
}

bool has_attr(hid_t obj, const char* name) { return H5Aexists(obj, name) > 0; }

std::string read_attr(hid_t obj, const std::string& fname, const char* name) {
  if (H5Aexists(obj, name) <= 0) throw input_error(fname, std::string("attribute ") + name, "missing");
  Id attr(H5Aopen(obj, name, H5P_DEFAULT), H5Aclose);
  Id ftype(H5Aget_type(attr), H5Tclose);
  if (H5Tget_class(ftype) != H5T_STRING) throw input_error(fname, std::string("attribute ") + name, "expected a string");
  if (H5Tis_variable_str(ftype) > 0) {
    Id type(H5Tcopy(H5T_C_S1), H5Tclose);
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
  Id type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, size);
  H5Tset_strpad(type, H5T_STR_NULLPAD);  // all `size` bytes are text (a null-terminated read would drop the last)
  H5Tset_cset(type, H5Tget_cset(ftype));
  if (H5Aread(attr, type, s.data()) < 0) throw input_error(fname, std::string("attribute ") + name, "cannot be read");
  s.resize(std::strlen(s.c_str()));
  return s;
}

// Fixed-length, null-padded strings in one Fletcher-32-checked chunk (see write_attr for why
// not variable-length).
void write_strings(hid_t file, const std::string& fname, const char* name, const std::vector<std::string>& values) {
  std::size_t width = 1;
  for (const auto& v : values) width = std::max(width, v.size());
  Id type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, width);
  H5Tset_strpad(type, H5T_STR_NULLPAD);
  H5Tset_cset(type, H5T_CSET_UTF8);
  hsize_t n = values.size();
  Id space(H5Screate_simple(1, &n, nullptr), H5Sclose);
  Id plist(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
  if (!nn::add_checksum(plist, 1, &n)) throw input_error(fname, name, "cannot set up the checksum filter");
  Id ds(H5Dcreate2(file, name, type, space, H5P_DEFAULT, plist, H5P_DEFAULT), H5Dclose);
  if (!ds.ok()) throw input_error(fname, name, "cannot create dataset");
  std::string packed(width * values.size(), '\0');
  for (std::size_t i = 0; i < values.size(); ++i) std::copy(values[i].begin(), values[i].end(), packed.begin() + i * width);
  if (n) check(H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, packed.data()), fname, name);
}

hid_t open_checked(hid_t file, const std::string& fname, const char* name, const std::vector<long long>& expect,
                   std::vector<hsize_t>& dims) {
  if (H5Lexists(file, name, H5P_DEFAULT) <= 0) throw input_error(fname, std::string("dataset ") + name, "missing");
  hid_t ds = H5Dopen2(file, name, H5P_DEFAULT);
  if (ds < 0) throw input_error(fname, std::string("dataset ") + name, "cannot be opened");
  Id space(H5Dget_space(ds), H5Sclose);
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

std::vector<std::string> read_strings(hid_t file, const std::string& fname, const char* name, long long expect) {
  std::vector<hsize_t> dims;
  Id ds(open_checked(file, fname, name, {expect}, dims), H5Dclose);
  Id ftype(H5Dget_type(ds), H5Tclose);
  if (H5Tget_class(ftype) != H5T_STRING) throw input_error(fname, std::string("dataset ") + name, "expected strings");
  if (H5Tis_variable_str(ftype) <= 0) {  // fixed-length, as this build writes; variable-length below: older files stay readable
    const std::size_t width = H5Tget_size(ftype);
    if (width == 0 || width > (1u << 20)) throw input_error(fname, std::string("dataset ") + name, "implausible string width");
    Id mem(H5Tcopy(ftype), H5Tclose);
    H5Tset_strpad(mem, H5T_STR_NULLPAD);
    std::string packed(width * dims[0], '\0');
    if (dims[0] && H5Dread(ds, mem, H5S_ALL, H5S_ALL, H5P_DEFAULT, packed.data()) < 0)
      throw input_error(fname, std::string("dataset ") + name, "cannot be read as strings (corrupt file?)");
    std::vector<std::string> out;
    out.reserve(dims[0]);
    for (std::size_t i = 0; i < dims[0]; ++i) {
      std::string v = packed.substr(i * width, width);
      v.resize(std::strlen(v.c_str()));
      out.push_back(std::move(v));
    }
    return out;
  }
  Id type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type, H5T_VARIABLE);
  H5Tset_cset(type, H5Tget_cset(ftype));
  std::vector<char*> ptrs(dims[0], nullptr);
  if (dims[0] && H5Dread(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, ptrs.data()) < 0)
    throw input_error(fname, std::string("dataset ") + name, "cannot be read as strings");
  std::vector<std::string> out;
  out.reserve(ptrs.size());
  for (char* p : ptrs) {
    out.emplace_back(p ? p : "");
    H5free_memory(p);
  }
  return out;
}

}  // namespace lidarsim::data::h5
