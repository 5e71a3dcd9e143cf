#include "nn/h5_memory_file.h"

#include <unistd.h>

#include <atomic>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"

namespace lidarsim::nn {

bool keep_compact(hid_t gcpl) {
  return H5Pset_link_phase_change(gcpl, 60000, 60000) >= 0 && H5Pset_attr_phase_change(gcpl, 60000, 60000) >= 0;
}

hid_t create_memory_file(const std::filesystem::path& name) {
  static std::atomic<int> counter{0};
  const hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
  if (fapl < 0) return -1;
  hid_t file = -1;
  // Grow the image 4 MiB at a time; backing_store = false: nothing is written on close.
  // STRONG: closing the file closes anything still open inside it.
  if (H5Pset_fapl_core(fapl, 4 << 20, false) >= 0 && H5Pset_fclose_degree(fapl, H5F_CLOSE_STRONG) >= 0 &&
      H5Pset_libver_bounds(fapl, H5F_LIBVER_V110, H5F_LIBVER_V110) >= 0) {
    // Names must be unique among open files; the path itself is never touched.
    const std::string unique = name.string() + ".mem." + std::to_string(::getpid()) + "." + std::to_string(counter++);
    const hid_t fcpl = H5Pcreate(H5P_FILE_CREATE);
    // No timestamps (the root group too): two saves of the same state are the same bytes.
    if (fcpl >= 0 && keep_compact(fcpl) && H5Pset_obj_track_times(fcpl, false) >= 0) file = H5Fcreate(unique.c_str(), H5F_ACC_TRUNC, fcpl, fapl);
    if (fcpl >= 0) H5Pclose(fcpl);
  }
  H5Pclose(fapl);
  return file;
}

hid_t open_memory_image(const MemoryImage& image, hid_t fapl) {
  static std::atomic<int> counter{0};
  if (image.size == 0) return -1;  // HDF5 takes an empty image for "no image" and would open the path
  if (H5Pset_fapl_core(fapl, 64 << 10, false) < 0 || H5Pset_file_image(fapl, const_cast<void*>(image.data), image.size) < 0)
    return -1;
  // The core driver refuses an image whose name exists on disk; this one never does.
  const std::string unique = image.name.string() + ".image." + std::to_string(::getpid()) + "." + std::to_string(counter++);
  return H5Fopen(unique.c_str(), H5F_ACC_RDONLY, fapl);
}

// HDF5's own metadata checksum (Jenkins lookup3), exported by libhdf5 though not in its public
// header.
extern "C" std::uint32_t H5_checksum_metadata(const void* data, std::size_t len, std::uint32_t initval);

namespace {

// HDF5 1.10.8's H5Fget_file_image writes the end-of-file address into the image's superblock
// (version 2 and later) without updating that block's checksum, and the file would not open.
// Layout: signature 8, version, sizes of offsets and lengths, flags, four addresses, checksum.
bool reseal_superblock(std::vector<unsigned char>& image) {
  if (image.size() < 12) return false;
  const unsigned version = image[8], offsets = image[9];
  if (version < 2) return true;  // older superblocks carry no checksum
  const std::size_t body = 12 + 4 * static_cast<std::size_t>(offsets);
  if (image.size() < body + 4) return false;
  const std::uint32_t sum = H5_checksum_metadata(image.data(), body, 0);
  std::memcpy(image.data() + body, &sum, 4);  // little-endian, as HDF5 stores it on every host we build on
  return true;
}

}  // namespace

void save_memory_file(hid_t file, const std::filesystem::path& path) {
  std::vector<unsigned char> image;
  bool ok = H5Fflush(file, H5F_SCOPE_GLOBAL) >= 0;
  if (ok) {
    const ssize_t size = H5Fget_file_image(file, nullptr, 0);
    ok = size > 0;
    if (ok) {
      image.resize(static_cast<std::size_t>(size));
      ok = H5Fget_file_image(file, image.data(), image.size()) == size && reseal_superblock(image);
    }
  }
  ok = H5Fclose(file) >= 0 && ok;  // in memory: nothing here can hit the disk
  if (!ok) throw input_error(path.string(), "file", "HDF5 could not build the file image");
  write_file_atomically(path, image.data(), image.size());
}

bool add_checksum(hid_t dcpl, int rank, const hsize_t* chunk) {
  for (int i = 0; i < rank; ++i)
    if (chunk[i] == 0) return true;
  return H5Pset_chunk(dcpl, rank, chunk) >= 0 && H5Pset_fletcher32(dcpl) >= 0;
}

}  // namespace lidarsim::nn
