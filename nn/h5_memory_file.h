#pragma once
// HDF5 files built in memory and written to disk by us. HDF5 (1.10) crashes in its exit handler
// when a file's close fails, e.g. on a full disk; with the in-memory ("core") driver and no
// backing store HDF5 never writes to disk, and the one write that can fail is our own checked
// write_file_atomically. The format is pinned to 1.8-and-later objects, whose headers carry
// checksums (v2 object headers), and datasets get Fletcher-32 via add_checksum().
#include <hdf5.h>

#include <filesystem>

#include "nn/memory_image.h"

namespace lidarsim::nn {

// Opens `image` read-only with `fapl` (the reader's own file access list, whose driver becomes
// the in-memory "core" driver holding a copy of the bytes; nothing is read from or written to
// disk). Returns a negative id on failure, as H5Fopen does.
hid_t open_memory_image(const MemoryImage& image, hid_t fapl);

// A new, empty in-memory HDF5 file (H5Fclose it, or let save_memory_file do so); `name` only
// labels it inside HDF5. Returns a negative id on failure.
hid_t create_memory_file(const std::filesystem::path& name);

// Flushes `file`, closes it and writes its bytes atomically to `path` (temporary + rename).
// Throws lidarsim::Error naming `path` when any step fails; `file` is closed in every case.
void save_memory_file(hid_t file, const std::filesystem::path& path);

// Keeps a group's links and attributes in its (checksummed) object header instead of "dense"
// storage in a fractal heap, whose blocks are neither checksummed nor deterministic in content.
// For every group creation property list of a file made by create_memory_file.
bool keep_compact(hid_t gcpl);

// Adds the Fletcher-32 checksum filter to a dataset creation property list, chunked as one
// chunk per `chunk` (datasets of zero elements stay contiguous and unfiltered). HDF5 checks
// the sum on every read. Returns false when HDF5 refuses.
bool add_checksum(hid_t dcpl, int rank, const hsize_t* chunk);

}  // namespace lidarsim::nn
