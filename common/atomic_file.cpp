#include "common/atomic_file.h"

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <system_error>
#include <unistd.h>

#include "common/error.h"

namespace lidarsim {
namespace fs = std::filesystem;

namespace {

// "<name>.tmp.<pid>" -> pid, or -1 when `file` is not such a temporary of `name` (any name
// when `name` is empty).
long temp_owner(const std::string& file, const std::string& name) {
  const std::size_t at = file.rfind(".tmp.");
  if (at == std::string::npos || at == 0) return -1;
  if (!name.empty() && file.compare(0, at, name) != 0) return -1;
  if (!name.empty() && at != name.size()) return -1;
  const std::string digits = file.substr(at + 5);
  if (digits.empty() || digits.size() > 9 || digits.find_first_not_of("0123456789") != std::string::npos) return -1;
  return std::stol(digits);
}

bool process_gone(long pid) { return pid > 0 && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH; }

int remove_stale(const fs::path& dir, const std::string& name) {
  std::error_code ec;
  int removed = 0;
  fs::directory_iterator it(dir.empty() ? fs::path(".") : dir, ec), end;
  for (; !ec && it != end; it.increment(ec)) {
    const long pid = temp_owner(it->path().filename().string(), name);
    if (pid < 0 || pid == ::getpid() || !process_gone(pid)) continue;
    std::error_code rm;
    if (fs::remove(it->path(), rm)) ++removed;
  }
  return removed;
}

}  // namespace

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
  write_file_atomically(path, contents.data(), contents.size());
}

void write_file_atomically(const std::filesystem::path& path, const void* data, std::size_t size) {
  AtomicFile file(path);
  // stdio rather than a stream: fwrite and fclose report errno (ENOSPC, EFBIG), and fclose's
  // flush of the last buffer is where a full disk shows for small files.
  std::FILE* out = std::fopen(file.temp_path().c_str(), "wb");
  if (!out) throw Error(path.string() + ": cannot open for writing: " + std::strerror(errno));
  const bool written = size == 0 || std::fwrite(data, 1, size, out) == size;
  int err = written ? 0 : errno;
  if (std::fclose(out) != 0 && !err) err = errno ? errno : EIO;
  if (!written || err)
    throw Error(path.string() + ": write failed (" + std::strerror(err ? err : EIO) +
                "; disk full or file-size limit?); the previous file is unchanged");
  file.commit();
}

int remove_stale_temp_files(const std::filesystem::path& final_path) {
  return remove_stale(final_path.parent_path(), final_path.filename().string());
}

int remove_stale_temp_files_in(const std::filesystem::path& dir) { return remove_stale(dir, ""); }

}  // namespace lidarsim
