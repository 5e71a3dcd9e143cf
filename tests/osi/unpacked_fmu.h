#pragma once
// build/lidarsim_osi.fmu unpacked into a temporary folder, as an importer unpacks it. The FMU's
// model library stays loaded once loaded (RTLD_NODELETE), so the tests of a process share one
// unpacked copy (unpacked_fmu()); a second, separate copy (unpacked_fmu_copy()) is what an
// importer that unpacks every instance into its own folder loads next to the first.
// LIDARSIM_TEST_FMU, when set, names another .fmu to unpack instead (an older build), or a folder
// holding one unpacked, which is copied without a shell (the ThreadSanitizer run of docs/osi.md
// preloads libtsan into this uninstrumented test, and /bin/sh crashes under it).
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace lidarsim::testing {

// The FMU unpacked into a folder named after `tag` and the process, removed when the object goes;
// dir is empty when unpacking failed.
struct UnpackedFmu {
  std::filesystem::path dir;
  explicit UnpackedFmu(const std::string& tag) {
    const std::filesystem::path d =
        std::filesystem::temp_directory_path() / ("lidarsim_fmu_" + tag + std::to_string(::getpid()));
    std::filesystem::remove_all(d);
    std::filesystem::create_directories(d);
    const char* other = std::getenv("LIDARSIM_TEST_FMU");
    const std::string fmu =
        other && *other ? std::string(other) : std::string(LIDARSIM_BINARY_DIR) + "/lidarsim_osi.fmu";
    std::error_code ec;
    if (std::filesystem::is_directory(fmu)) {
      std::filesystem::copy(fmu, d, std::filesystem::copy_options::recursive, ec);
      if (!ec) dir = d;
    } else if (std::system(("cd " + d.string() + " && cmake -E tar xf " + fmu).c_str()) == 0) {
      dir = d;
    }
  }
  ~UnpackedFmu() {
    std::error_code ec;
    if (!dir.empty()) std::filesystem::remove_all(dir, ec);
  }
  UnpackedFmu(const UnpackedFmu&) = delete;
  UnpackedFmu& operator=(const UnpackedFmu&) = delete;
};

// The process's shared copy (empty when unpacking failed); removed when the process exits.
inline const std::filesystem::path& unpacked_fmu() {
  static const UnpackedFmu u("");
  return u.dir;
}

// A second copy in a folder of its own, for the tests of two copies in one process.
inline const std::filesystem::path& unpacked_fmu_copy() {
  static const UnpackedFmu u("copy_");
  return u.dir;
}

}  // namespace lidarsim::testing
