// lidarsim_osi.fmu used the way an FMI importer uses it: unzip, read modelDescription.xml,
// dlopen binaries/linux64/lidarsim_osi.so, fmi2Instantiate with the resources URI, pass each
// SensorView through OSMPSensorViewIn.base.lo/base.hi/size, fmi2DoStep, decode the SensorData
// behind OSMPSensorDataOut.base.lo/base.hi/size.
#include <dlfcn.h>
#include <gtest/gtest.h>

#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "unpacked_fmu.h"
#include "infer/fmu/fmi2.h"
#include "osi/osi3_subset.pb.h"
#include "osi/scenario_trace.h"
#include "sensor/scenario.h"
#include "tests/support/file_bytes.h"

using lidarsim::testing::read_bytes;

namespace {

namespace fs = std::filesystem;

std::string attribute(const std::string& xml, const std::string& name) {
  const auto at = xml.find(" " + name + "=\"");
  if (at == std::string::npos) return "";
  const auto start = at + name.size() + 3;
  return xml.substr(start, xml.find('"', start) - start);
}

// Importer-side log: everything the FMU reports at warning level or above (e.g. a failed dlmopen).
std::string g_warnings;
void logger(fmi2ComponentEnvironment, fmi2String, fmi2Status status, fmi2String category, fmi2String message, ...) {
  char text[2048];
  va_list args;
  va_start(args, message);
  std::vsnprintf(text, sizeof text, message, args);
  va_end(args);
  if (status >= fmi2Warning) g_warnings += std::string(category) + ": " + text + "\n";
}

template <typename F>
F* symbol(void* lib, const char* name) {
  return reinterpret_cast<F*>(dlsym(lib, name));
}

}  // namespace

TEST(OsiFmu, ImporterGetsSensorDataForEachSensorViewThroughOsmpPointers) {
  const fs::path fmu = fs::path(LIDARSIM_BINARY_DIR) / "lidarsim_osi.fmu";
  ASSERT_TRUE(fs::exists(fmu)) << fmu;
  const fs::path& dir = lidarsim::testing::unpacked_fmu();
  ASSERT_FALSE(dir.empty()) << "cannot unpack " << fmu;

  const std::string xml = read_bytes(dir / "modelDescription.xml");
  EXPECT_EQ(attribute(xml, "fmiVersion"), "2.0");
  EXPECT_EQ(attribute(xml, "variableNamingConvention"), "structured");
  EXPECT_NE(xml.find("<osmp:osmp version="), std::string::npos);
  for (const char* v : {"OSMPSensorViewIn.base.lo", "OSMPSensorViewIn.base.hi", "OSMPSensorViewIn.size",
                        "OSMPSensorDataOut.base.lo", "OSMPSensorDataOut.base.hi", "OSMPSensorDataOut.size"})
    EXPECT_NE(xml.find(std::string("name=\"") + v + "\""), std::string::npos) << v;
  EXPECT_NE(xml.find("type=SensorView; version="), std::string::npos);
  EXPECT_NE(xml.find("type=SensorData; version="), std::string::npos);
  const std::string guid = attribute(xml, "guid");
  const std::string id = attribute(xml, "modelIdentifier");
  ASSERT_EQ(id, "lidarsim_osi");

  void* lib = dlopen((dir / "binaries" / "linux64" / (id + ".so")).c_str(), RTLD_NOW | RTLD_LOCAL);
  ASSERT_NE(lib, nullptr) << dlerror();
  auto* instantiate = symbol<fmi2InstantiateTYPE>(lib, "fmi2Instantiate");
  auto* setup = symbol<fmi2SetupExperimentTYPE>(lib, "fmi2SetupExperiment");
  auto* enter = symbol<fmi2EnterInitializationModeTYPE>(lib, "fmi2EnterInitializationMode");
  auto* exit_init = symbol<fmi2ExitInitializationModeTYPE>(lib, "fmi2ExitInitializationMode");
  auto* set_int = symbol<fmi2SetIntegerTYPE>(lib, "fmi2SetInteger");
  auto* get_int = symbol<fmi2GetIntegerTYPE>(lib, "fmi2GetInteger");
  auto* do_step = symbol<fmi2DoStepTYPE>(lib, "fmi2DoStep");
  auto* terminate = symbol<fmi2TerminateTYPE>(lib, "fmi2Terminate");
  auto* free_instance = symbol<fmi2FreeInstanceTYPE>(lib, "fmi2FreeInstance");
  for (void* f : {reinterpret_cast<void*>(instantiate), reinterpret_cast<void*>(set_int),
                  reinterpret_cast<void*>(do_step), reinterpret_cast<void*>(free_instance),
                  dlsym(lib, "fmi2GetFMUstate"), dlsym(lib, "fmi2GetBooleanStatus")})
    ASSERT_NE(f, nullptr);
  // Only fmi2* is exported: the model's own symbols cannot clash with an importer's.
  const fs::path so = dir / "binaries" / "linux64" / (id + ".so");
  FILE* nm = popen(("nm -D --defined-only " + so.string()).c_str(), "r");
  ASSERT_NE(nm, nullptr);
  char line[512];
  int exported = 0;
  while (fgets(line, sizeof line, nm)) {
    std::istringstream fields(line);
    std::string address, kind, name;
    fields >> address >> kind >> name;
    if (kind != "T" && kind != "W" && kind != "D" && kind != "B") continue;
    EXPECT_EQ(name.rfind("fmi2", 0), 0u) << "exported: " << name;
    ++exported;
  }
  pclose(nm);
  EXPECT_GE(exported, 30);

  // This test process has our osi3 messages registered in its own libprotobuf (like an importer with
  // the official OSI): the FMU's model must live in its own namespace or loading it aborts.
  fmi2CallbackFunctions callbacks{};
  callbacks.logger = logger;
  const std::string resources = "file://" + fs::absolute(dir / "resources").string();
  EXPECT_EQ(instantiate("sensor", fmi2CoSimulation, "{not-this-fmu}", resources.c_str(), &callbacks, 0, 0), nullptr);
  fmi2Component c = instantiate("sensor", fmi2CoSimulation, guid.c_str(), resources.c_str(), &callbacks, 0, 0);
  ASSERT_NE(c, nullptr) << g_warnings;
  EXPECT_NE(g_warnings.find("GUID {not-this-fmu} is not this FMU's"), std::string::npos) << g_warnings;
  g_warnings.clear();
  ASSERT_EQ(setup(c, 0, 0, 0, 0, 0), fmi2OK);
  ASSERT_EQ(enter(c), fmi2OK);
  ASSERT_EQ(exit_init(c), fmi2OK);

  const auto scenario =
      lidarsim::sensor::read_scenario(std::string(LIDARSIM_SOURCE_DIR) + "/data/scenarios/demo_urban.json");
  const fmi2ValueReference in_vr[3] = {0, 1, 2}, out_vr[3] = {3, 4, 5};
  std::string previous_bytes;
  const char* previous_address = nullptr;
  for (int k = 0; k < 3; ++k) {
    osi3::SensorView view;
    lidarsim::osi::sensor_view_from_scenario(scenario, scenario.frame_time(k), view);
    const std::string bytes = view.SerializeAsString();
    const auto address = reinterpret_cast<std::uintptr_t>(bytes.data());
    const fmi2Integer in[3] = {static_cast<fmi2Integer>(static_cast<std::uint32_t>(address & 0xffffffffu)),
                               static_cast<fmi2Integer>(static_cast<std::uint32_t>(std::uint64_t(address) >> 32)),
                               static_cast<fmi2Integer>(bytes.size())};
    ASSERT_EQ(set_int(c, in_vr, 3, in), fmi2OK);
    ASSERT_EQ(do_step(c, scenario.frame_time(k), 0.1, 1), fmi2OK) << "step " << k;
    // OSMP: the previous step's output stays valid until the end of this step.
    if (previous_address) {
      EXPECT_EQ(std::string(previous_address, previous_bytes.size()), previous_bytes);
    }
    fmi2Integer out[3] = {0, 0, 0};
    ASSERT_EQ(get_int(c, out_vr, 3, out), fmi2OK);
    const auto out_address = static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[0])) |
                             static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[1])) << 32;
    ASSERT_NE(out_address, 0u);
    ASSERT_GT(out[2], 0);
    previous_address = reinterpret_cast<const char*>(out_address);
    previous_bytes.assign(previous_address, static_cast<std::size_t>(out[2]));
    osi3::SensorData data;
    ASSERT_TRUE(data.ParseFromArray(previous_address, out[2]));
    EXPECT_EQ(data.timestamp().nanos(), view.timestamp().nanos());
    EXPECT_EQ(data.sensor_id().value(), view.sensor_id().value());
    ASSERT_EQ(data.feature_data().lidar_sensor_size(), 1);
    EXPECT_GT(data.feature_data().lidar_sensor(0).detection_size(), 10000);
    if (k == 2) {
      EXPECT_GT(data.moving_object_size(), 0);
    }
  }
  // A zero pointer means no input: no output, no error.
  const fmi2Integer none[3] = {0, 0, 0};
  ASSERT_EQ(set_int(c, in_vr, 3, none), fmi2OK);
  ASSERT_EQ(do_step(c, 0.3, 0.1, 1), fmi2OK);
  fmi2Integer out[3] = {1, 1, 1};
  ASSERT_EQ(get_int(c, out_vr, 3, out), fmi2OK);
  EXPECT_EQ(out[2], 0);
  EXPECT_EQ(g_warnings, "");
  EXPECT_EQ(terminate(c), fmi2OK);
  free_instance(c);
  dlclose(lib);
}
