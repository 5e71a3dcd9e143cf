#pragma once
// Runs code in a child process whose files may not grow past a limit (RLIMIT_FSIZE), as on a
// full disk: writes past it fail with EFBIG (SIGXFSZ is ignored). The child ends through
// std::exit, so library exit handlers (HDF5's) run as they would in a command.
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <string>

namespace lidarsim::testing {

// Describes a wait status: "exit 3", "signal 11".
inline std::string describe_status(int status) {
  if (WIFEXITED(status)) return "exit " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return "signal " + std::to_string(WTERMSIG(status));
  return "status " + std::to_string(status);
}

// fn() returns the child's exit code; the result is the wait status, described.
template <typename F>
std::string run_with_file_size_limit(rlim_t bytes, F&& fn) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::signal(SIGXFSZ, SIG_IGN);
    const rlimit limit{bytes, bytes};
    ::setrlimit(RLIMIT_FSIZE, &limit);
    std::exit(fn());
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  return describe_status(status);
}

}  // namespace lidarsim::testing
