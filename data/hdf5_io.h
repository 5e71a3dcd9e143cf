#pragma once
// Small HDF5 helpers shared by the dataset writer and reader: an owning id, string and integer
// attributes, variable-length string datasets, and a checked open that names the file and field.
#include <hdf5.h>

#include <string>
#include <vector>

namespace lidarsim::data::h5 {

// Owns one HDF5 id and closes it with the matching function.
class Id {
 public:
  Id(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  ~Id() {
    if (id_ >= 0) close_(id_);
  }
  Id(const Id&) = delete;
  Id& operator=(const Id&) = delete;
  operator hid_t() const { return id_; }
  bool ok() const { return id_ >= 0; }

 private:
  hid_t id_;
  herr_t (*close_)(hid_t);
};

void quiet();  // HDF5 prints its own error stack otherwise; ours name the file and field
void check(herr_t status, const std::string& file, const std::string& what);

void write_attr(hid_t obj, const std::string& fname, const char* name, const std::string& value);
void write_attr_int(hid_t obj, const std::string& fname, const char* name, long long value);
bool has_attr(hid_t obj, const char* name);
std::string read_attr(hid_t obj, const std::string& fname, const char* name);

// Whole string dataset in one go (small lists: sources, frame ids of a short import).
void write_strings(hid_t file, const std::string& fname, const char* name, const std::vector<std::string>& values);
std::vector<std::string> read_strings(hid_t file, const std::string& fname, const char* name, long long expect);

// Opens a dataset and checks its rank and (where given, >= 0) its dimensions; the caller owns it.
hid_t open_checked(hid_t file, const std::string& fname, const char* name, const std::vector<long long>& expect,
                   std::vector<hsize_t>& dims);

}  // namespace lidarsim::data::h5
