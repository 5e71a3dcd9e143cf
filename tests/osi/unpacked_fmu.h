#pragma once
// build/lidarsim_osi.fmu unpacked once per test process. The FMU's model library stays loaded
// once loaded (RTLD_NODELETE) and registers its schema in the process's libprotobuf, so a second
// copy of it from another folder would register the same .proto file again and abort: every test
// of a process loads the one copy.
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace lidarsim::testing {

// The folder (empty when unpacking failed); removed when the process exits.
inline const std::filesystem::path& unpacked_fmu() {
  struct Unpacked {
    std::filesystem::path dir;
    Unpacked() {
      const std::filesystem::path d =
          std::filesystem::temp_directory_path() / ("lidarsim_fmu_" + std::to_string(::getpid()));
      std::filesystem::remove_all(d);
      std::filesystem::create_directories(d);
      const std::string fmu = std::string(LIDARSIM_BINARY_DIR) + "/lidarsim_osi.fmu";
      if (std::system(("cd " + d.string() + " && cmake -E tar xf " + fmu).c_str()) == 0) dir = d;
    }
    ~Unpacked() {
      std::error_code ec;
      if (!dir.empty()) std::filesystem::remove_all(dir, ec);
    }
  };
  static const Unpacked u;
  return u.dir;
}

}  // namespace lidarsim::testing
