// lidarsim_osi.fmu carries its own model: its two libraries need nothing beyond the C
// and C++ runtime, export only their interface (fmi2* / lidarsim_osi_model_*), import no symbol
// but the runtime's, and a process that runs the FMU (tests/osi/importer, which links nothing
// but the runtime) loads no other object: no HDF5, no libgomp, no libprotobuf (the SensorView is
// decoded and the SensorData encoded by hand). Its SensorData are the bytes the in-process model
// gives from the HDF5 checkpoint, so shipping the UNet as a weights file changed nothing.
#include <gtest/gtest.h>

#include "tests/support/file_bytes.h"
#include "tests/support/sanitizer.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "../data/temp_dir.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/scenario_trace.h"
#include "sensor/scenario.h"

using lidarsim::testing::read_bytes;

namespace {

namespace fs = std::filesystem;

// glibc (with libm, libdl, libpthread, the loader), libstdc++ and libgcc_s.
const std::set<std::string> kRuntimes = {"libc.so.6",       "libm.so.6",     "libdl.so.2",
                                         "libpthread.so.0", "librt.so.1",    "ld-linux-x86-64.so.2",
                                         "libstdc++.so.6",  "libgcc_s.so.1"};
const char* kLibraries[] = {"lidarsim_osi.so", "lidarsim_osi_model.so"};

std::vector<std::string> lines_of(const std::string& command) {
  std::vector<std::string> lines;
  FILE* p = popen(command.c_str(), "r");
  if (!p) return lines;
  char line[4096];
  while (fgets(line, sizeof line, p)) {
    std::string s(line);
    if (!s.empty() && s.back() == '\n') s.pop_back();
    lines.push_back(s);
  }
  EXPECT_EQ(pclose(p), 0) << command;
  return lines;
}

// The FMU unpacked into `dir` (what an importer does first).
fs::path unpack(const lidarsim::testing::TempDir& dir) {
  const fs::path fmu = fs::path(LIDARSIM_BINARY_DIR) / "lidarsim_osi.fmu";
  EXPECT_TRUE(fs::exists(fmu)) << fmu;
  EXPECT_EQ(std::system(("cd " + dir.path().string() + " && cmake -E tar xf " + fmu.string()).c_str()), 0);
  return dir.path();
}

void append_message(std::string& trace, const std::string& bytes) {
  for (int b = 0; b < 4; ++b) trace.push_back(static_cast<char>((bytes.size() >> (8 * b)) & 0xffu));
  trace += bytes;
}

}  // namespace

TEST(OsiFmuSelfContained, BinariesNeedOnlyTheCAndCxxRuntime) {
  // A sanitized FMU needs the sanitizers' runtimes (libasan, libubsan) by construction.
  if (lidarsim::testing::kSanitized) GTEST_SKIP() << "the sanitized FMU links the sanitizer runtimes";
  lidarsim::testing::TempDir dir;
  const fs::path root = unpack(dir);
  for (const char* name : kLibraries) {
    const fs::path so = root / "binaries" / "linux64" / name;
    ASSERT_TRUE(fs::exists(so)) << so;
    int needed = 0;
    for (const std::string& line : lines_of("readelf -dW " + so.string())) {
      if (line.find("(NEEDED)") == std::string::npos) continue;
      const auto open = line.find('['), close = line.find(']');
      const std::string lib = line.substr(open + 1, close - open - 1);
      EXPECT_TRUE(kRuntimes.count(lib)) << name << " needs " << lib;
      ++needed;
    }
    EXPECT_GT(needed, 0) << name;
  }
}

TEST(OsiFmuSelfContained, ExportsOnlyItsInterfaceAndImportsOnlyFromTheRuntime) {
  // A sanitized FMU needs the sanitizers' runtimes (libasan, libubsan) by construction.
  if (lidarsim::testing::kSanitized) GTEST_SKIP() << "the sanitized FMU links the sanitizer runtimes";
  lidarsim::testing::TempDir dir;
  const fs::path root = unpack(dir);
  for (const char* name : kLibraries) {
    const std::string prefix = name == std::string("lidarsim_osi.so") ? "fmi2" : "lidarsim_osi_model_";
    const fs::path so = root / "binaries" / "linux64" / name;
    int exported = 0;
    // nm -D lines: "<address> <kind> <name>[@version]" for defined, "<kind> <name>@version" for undefined.
    for (const std::string& line : lines_of("nm -D " + so.string())) {
      std::istringstream fields(line);
      std::vector<std::string> f{std::istream_iterator<std::string>(fields), std::istream_iterator<std::string>()};
      if (f.size() == 2) {  // undefined: every one must come from a runtime's version node
        const std::string& symbol = f[1];
        if (f[0] == "w") continue;  // weak, optional (e.g. __gmon_start__, _ITM_*)
        EXPECT_NE(symbol.rfind("H5", 0), 0u) << name << " references HDF5: " << symbol;
        EXPECT_EQ(symbol.find("protobuf"), std::string::npos) << name << " references libprotobuf: " << symbol;
        const auto at = symbol.find('@');
        const std::string version = at == std::string::npos ? "" : symbol.substr(at + 1);
        const bool runtime = version.rfind("GLIBC_", 0) == 0 || version.rfind("GLIBCXX_", 0) == 0 ||
                             version.rfind("CXXABI_", 0) == 0 || version.rfind("GCC_", 0) == 0;
        EXPECT_TRUE(runtime) << name << " imports " << symbol << " from outside the C/C++ runtime";
      } else if (f.size() == 3 && f[1] != "A") {  // defined (A: the version nodes themselves)
        EXPECT_EQ(f[2].rfind(prefix, 0), 0u) << name << " exports " << f[2];
        ++exported;
      }
    }
    EXPECT_GE(exported, 3) << name;
  }
}

// The importer process (runtime only) loads the FMU's two libraries and nothing else; its
// SensorData are the in-process model's bytes (HDF5 checkpoint) for the same SensorViews.
TEST(OsiFmuSelfContained, ImporterLoadsOnlyTheRuntimeAndGetsTheInProcessBytes) {
  // A sanitized FMU needs the sanitizers' runtimes (libasan, libubsan) by construction.
  if (lidarsim::testing::kSanitized) GTEST_SKIP() << "the sanitized FMU links the sanitizer runtimes";
  lidarsim::testing::TempDir dir;
  const fs::path root = unpack(dir);
  const auto scenario =
      lidarsim::sensor::read_scenario(std::string(LIDARSIM_SOURCE_DIR) + "/data/scenarios/demo_urban.json");
  auto runner = lidarsim::infer::OsiRunner::from_files(root / "resources" / "sensor.json",
                                                        root / "resources" / "kpi_pointrcnn.json",
                                                        std::string(LIDARSIM_SOURCE_DIR) + "/data/models/intensity_unet.h5");
  std::string views, expected;
  for (int k = 0; k < 3; ++k) {
    osi3::SensorView view;
    lidarsim::osi::sensor_view_from_scenario(scenario, scenario.frame_time(k), view);
    append_message(views, view.SerializeAsString());
    osi3::SensorData data;
    runner.step(view, k, "in-process", data);
    append_message(expected, data.SerializeAsString());
  }
  std::ofstream(dir / "sv.osi", std::ios::binary) << views;

  const std::string command = "LD_DEBUG=files LD_DEBUG_OUTPUT=" + (dir / "ld").string() + " " +
                              LIDARSIM_FMU_IMPORTER + " " + root.string() + " " + (dir / "sv.osi").string() + " " +
                              (dir / "sd.osi").string();
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  EXPECT_TRUE(read_bytes(dir / "sd.osi") == expected) << "the FMU's SensorData differ from the in-process model's";

  // LD_DEBUG=files: "file=<name> [0];  generating link map" for every object the loader maps.
  std::set<std::string> loaded;
  for (const auto& entry : fs::directory_iterator(dir.path()))
    if (entry.path().filename().string().rfind("ld.", 0) == 0) {
      std::istringstream log(read_bytes(entry.path()));
      for (std::string line; std::getline(log, line);) {
        const auto at = line.find("file="), end = line.find(" [");
        if (at == std::string::npos || end == std::string::npos || line.find("generating link map") == std::string::npos)
          continue;
        loaded.insert(fs::path(line.substr(at + 5, end - at - 5)).filename().string());
      }
    }
  EXPECT_TRUE(loaded.count("lidarsim_osi.so") && loaded.count("lidarsim_osi_model.so"));
  for (const std::string& lib : loaded)
    EXPECT_TRUE(kRuntimes.count(lib) || lib == "lidarsim_osi.so" || lib == "lidarsim_osi_model.so")
        << "the FMU's process loaded " << lib;
}
