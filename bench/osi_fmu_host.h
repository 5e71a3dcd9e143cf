#pragma once
// The OSMP FMU driven as an importer drives it, for the OSI benchmarks: unzip into a temporary
// folder, dlopen the entry library, fmi2Instantiate with the resources URI, initialise, then per
// frame set the SensorView pointer integers, fmi2DoStep and read the SensorData pointer integers.
// Errors throw lidarsim::Error.
#include <dlfcn.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <string_view>

#include "common/error.h"
#include "infer/fmu/fmi2.h"

namespace lidarsim::bench {

class FmuHost {
 public:
  explicit FmuHost(const std::filesystem::path& fmu, const char* instance = "bench") {
    namespace fs = std::filesystem;
    if (!fs::exists(fmu)) throw Error(fmu.string() + ": no such file (build lidarsim_osi_fmu_package)");
    char tmpl[] = "/tmp/bench_osi_fmu.XXXXXX";
    if (!mkdtemp(tmpl)) throw Error("cannot make a temporary folder");
    dir_ = tmpl;
    if (std::system(("cd " + dir_.string() + " && cmake -E tar xf " + fs::absolute(fmu).string()).c_str()) != 0)
      throw Error(fmu.string() + ": cannot be unpacked");
    std::ifstream xml_file(dir_ / "modelDescription.xml");
    std::stringstream xml;
    xml << xml_file.rdbuf();
    const std::string guid = attribute(xml.str(), "guid"), id = attribute(xml.str(), "modelIdentifier");
    lib_ = dlopen((dir_ / "binaries" / "linux64" / (id + ".so")).c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!lib_) throw Error(std::string("dlopen: ") + dlerror());
    auto* instantiate = symbol<fmi2InstantiateTYPE>("fmi2Instantiate");
    auto* setup = symbol<fmi2SetupExperimentTYPE>("fmi2SetupExperiment");
    auto* enter = symbol<fmi2EnterInitializationModeTYPE>("fmi2EnterInitializationMode");
    auto* exit_init = symbol<fmi2ExitInitializationModeTYPE>("fmi2ExitInitializationMode");
    set_int_ = symbol<fmi2SetIntegerTYPE>("fmi2SetInteger");
    get_int_ = symbol<fmi2GetIntegerTYPE>("fmi2GetInteger");
    do_step_ = symbol<fmi2DoStepTYPE>("fmi2DoStep");
    terminate_ = symbol<fmi2TerminateTYPE>("fmi2Terminate");
    free_instance_ = symbol<fmi2FreeInstanceTYPE>("fmi2FreeInstance");
    callbacks_.logger = logger;
    const std::string resources = "file://" + (dir_ / "resources").string();
    c_ = instantiate(instance, fmi2CoSimulation, guid.c_str(), resources.c_str(), &callbacks_, 0, 0);
    if (!c_) throw Error("fmi2Instantiate failed");
    if (setup(c_, 0, 0, 0, 0, 0) != fmi2OK || enter(c_) != fmi2OK || exit_init(c_) != fmi2OK)
      throw Error("FMU initialisation failed");
  }
  FmuHost(const FmuHost&) = delete;
  FmuHost& operator=(const FmuHost&) = delete;
  ~FmuHost() {
    if (c_) {
      terminate_(c_);
      free_instance_(c_);
    }
    if (lib_) dlclose(lib_);
    std::error_code ignored;
    std::filesystem::remove_all(dir_, ignored);
  }

  // One frame: the serialized SensorView in, the SensorData out (valid until the second step after).
  std::string_view step(const std::string& sensor_view, double t, double dt) {
    const auto address = reinterpret_cast<std::uintptr_t>(sensor_view.data());
    const fmi2Integer in[3] = {static_cast<fmi2Integer>(static_cast<std::uint32_t>(address & 0xffffffffu)),
                               static_cast<fmi2Integer>(static_cast<std::uint32_t>(std::uint64_t(address) >> 32)),
                               static_cast<fmi2Integer>(sensor_view.size())};
    const fmi2ValueReference in_vr[3] = {0, 1, 2}, out_vr[3] = {3, 4, 5};
    fmi2Integer out[3] = {0, 0, 0};
    if (set_int_(c_, in_vr, 3, in) != fmi2OK) throw Error("fmi2SetInteger failed at t = " + std::to_string(t));
    if (do_step_(c_, t, dt, 1) != fmi2OK) throw Error("fmi2DoStep failed at t = " + std::to_string(t));
    if (get_int_(c_, out_vr, 3, out) != fmi2OK || out[2] <= 0) throw Error("no SensorData at t = " + std::to_string(t));
    const auto out_address = static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[0])) |
                             static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[1])) << 32;
    return {reinterpret_cast<const char*>(out_address), static_cast<std::size_t>(out[2])};
  }

 private:
  static std::string attribute(const std::string& xml, const std::string& name) {
    const auto at = xml.find(" " + name + "=\"");
    if (at == std::string::npos) throw Error("modelDescription.xml has no " + name);
    const auto start = at + name.size() + 3;
    return xml.substr(start, xml.find('"', start) - start);
  }
  template <typename F>
  F* symbol(const char* name) {
    auto* f = reinterpret_cast<F*>(dlsym(lib_, name));
    if (!f) throw Error(std::string("the FMU does not export ") + name);
    return f;
  }
  static void logger(fmi2ComponentEnvironment, fmi2String, fmi2Status status, fmi2String category,
                     fmi2String message, ...) {
    if (status >= fmi2Warning) std::fprintf(stderr, "fmu %s: %s\n", category, message);
  }

  std::filesystem::path dir_;
  void* lib_ = nullptr;
  fmi2Component c_ = nullptr;
  fmi2CallbackFunctions callbacks_{};
  fmi2SetIntegerTYPE* set_int_ = nullptr;
  fmi2GetIntegerTYPE* get_int_ = nullptr;
  fmi2DoStepTYPE* do_step_ = nullptr;
  fmi2TerminateTYPE* terminate_ = nullptr;
  fmi2FreeInstanceTYPE* free_instance_ = nullptr;
};

}  // namespace lidarsim::bench
