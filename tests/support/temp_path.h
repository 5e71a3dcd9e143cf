#pragma once
// A name in the temporary folder that belongs to this process alone. ctest runs the tests of one
// file side by side (each test its own process), and other checkouts' suites may run on the same
// machine at the same time: a fixed name there is shared, and one test reads another's output.
// What is named here is removed when the process ends (not by a forked child that exits).
#include <unistd.h>

#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

namespace lidarsim::testing {

namespace detail {
struct TempPaths {
  pid_t owner = ::getpid();
  std::vector<std::filesystem::path> paths;
  ~TempPaths() {
    if (::getpid() != owner) return;
    std::error_code ec;
    for (const auto& p : paths) std::filesystem::remove_all(p, ec);
  }
};
inline TempPaths& temp_paths() {
  static TempPaths all;
  return all;
}
}  // namespace detail

inline std::filesystem::path temp_path(const std::string& name) {
  const auto p = std::filesystem::temp_directory_path() / ("lidarsim_" + std::to_string(::getpid()) + "_" + name);
  detail::temp_paths().paths.push_back(p);
  return p;
}

}  // namespace lidarsim::testing
