#include "common/atomic_file.h"

#include <fstream>
#include <system_error>
#include <unistd.h>

#include "common/error.h"

namespace lidarsim {

AtomicFile::AtomicFile(std::filesystem::path final_path) : final_(std::move(final_path)) {
  if (final_.has_parent_path()) std::filesystem::create_directories(final_.parent_path());
  temp_ = final_;
  temp_ += ".tmp." + std::to_string(::getpid());
}

AtomicFile::~AtomicFile() {
  if (!committed_) {
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
  }
}

void AtomicFile::commit() {
  std::error_code ec;
  std::filesystem::rename(temp_, final_, ec);
  if (ec) throw Error(final_.string() + ": cannot rename from " + temp_.string() + ": " + ec.message());
  committed_ = true;
}

void write_file_atomically(const std::filesystem::path& path, const std::string& contents) {
  AtomicFile file(path);
  {
    std::ofstream out(file.temp_path(), std::ios::binary);
    if (!out) throw Error(path.string() + ": cannot open for writing");
    out.write(contents.data(), static_cast<std::streamsize>(contents.size()));
    if (!out) throw Error(path.string() + ": write failed");
  }
  file.commit();
}

}  // namespace lidarsim
