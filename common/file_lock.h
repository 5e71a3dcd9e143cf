#pragma once
// An exclusive lock on an output, so two runs never write the same file at once (the second
// would silently win). flock() on "<path>.lock": the kernel drops it when the process ends,
// even on kill -9, so a stale lock file never blocks the next run.
#include <filesystem>

namespace lidarsim {

class OutputLock {
 public:
  // Throws lidarsim::Error naming `path` when another process holds the lock.
  explicit OutputLock(const std::filesystem::path& path);
  ~OutputLock();
  OutputLock(const OutputLock&) = delete;
  OutputLock& operator=(const OutputLock&) = delete;

 private:
  int fd_ = -1;
};

}  // namespace lidarsim
