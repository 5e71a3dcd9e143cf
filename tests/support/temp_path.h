#pragma once
// A name in the temporary folder that belongs to this process alone. ctest runs the tests of one
// file side by side (each test its own process), and other checkouts' suites may run on the same
// machine at the same time: a fixed name there is shared, and one test reads another's output.
#include <unistd.h>

#include <filesystem>
#include <string>

namespace lidarsim::testing {

inline std::filesystem::path temp_path(const std::string& name) {
  return std::filesystem::temp_directory_path() / ("lidarsim_" + std::to_string(::getpid()) + "_" + name);
}

}  // namespace lidarsim::testing
