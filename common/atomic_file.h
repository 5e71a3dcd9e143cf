#pragma once
// Write-then-rename, so a killed run never leaves a torn checkpoint or output behind.
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

// Convenience: write a whole text/binary string atomically.
void write_file_atomically(const std::filesystem::path& path, const std::string& contents);

}  // namespace lidarsim
