#pragma once
// Write-then-rename, so a killed run never leaves a torn checkpoint or output behind.
#include <cstddef>
#include <filesystem>
#include <string>

namespace lidarsim {

class AtomicFile {
 public:
  // The final path; the data go to a temporary sibling until commit().
  explicit AtomicFile(std::filesystem::path final_path);
  ~AtomicFile();  // removes the temporary file if commit() was never reached
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  const std::filesystem::path& temp_path() const { return temp_; }
  const std::filesystem::path& final_path() const { return final_; }
  void commit();  // rename temp -> final (atomic on one file system)

 private:
  std::filesystem::path final_, temp_;
  bool committed_ = false;
};

// Convenience: write a whole text/binary string atomically. Every write and the close are
// checked (a full disk or a file-size limit is an Error, and the old file stays).
void write_file_atomically(const std::filesystem::path& path, const std::string& contents);
void write_file_atomically(const std::filesystem::path& path, const void* data, std::size_t size);

// Removes temporaries "<name>.tmp.<pid>" that a killed run left beside `final_path` (only those
// whose process no longer exists); returns how many were removed.
int remove_stale_temp_files(const std::filesystem::path& final_path);
// The same for every file of a folder (e.g. an output folder of many files).
int remove_stale_temp_files_in(const std::filesystem::path& dir);

}  // namespace lidarsim
