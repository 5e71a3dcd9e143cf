// lidarsim as an OSMP sensor model FMU (FMI 2.0 Co-Simulation; OSI Sensor Model Packaging):
// osi3.SensorView in through OSMPSensorViewIn.base.lo / base.hi / size, osi3.SensorData out
// through OSMPSensorDataOut.base.lo / base.hi / size, one frame per fmi2DoStep, computed by the
// same OsiRunner as `lidar-infer osi`.
//
// This library holds only the FMI side and passes bytes; the model (lidarsim_osi_model.so, next
// to it) is dlopen'ed with its symbols kept local. Neither library links libprotobuf or exports
// anything but its entry points (exports.map, model_exports.map), so the model keeps nothing in a
// process-wide registry: an importer's own libprotobuf and OSI classes do not meet ours, and an
// importer that unpacks the FMU once per instance may load two copies side by side
// (tests/osi/test_fmu_multi.cpp). dlmopen is not used: a second libc in the process shares the
// threads' pthread key slots with the first and corrupted the importer's thread-local data.
//
// The model files (intensity_unet.weights, kpi_pointrcnn.json and sensor.json, a scenario whose
// sensor block gives beams, field of view and range) are read from the FMU's resources folder
// (fmuResourceLocation), else from the resources folder of the unpacked FMU the library sits in
// (binaries/linux64/../../resources), else from a "resources" folder next to the library.
//
// The String parameter `sensor` (value reference 6, settable until fmi2ExitInitializationMode)
// picks the beam layout: a file of resources/sensors/ without ".json" (the bundled data/sensors/
// layouts) or a path to a layout JSON; empty keeps sensor.json's beams. A car with several lidars
// instantiates this FMU once per lidar, each with its own layout and its own SensorView (mount,
// sensor_id); instances share nothing and may step in parallel threads.
//
// OSMP buffer lifetimes: the input buffer is only read during fmi2DoStep; the output buffer stays
// valid until the second fmi2DoStep after the one that produced it (two buffers, alternating).
#include <dlfcn.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <exception>
#include <filesystem>
#include <memory>
#include <string>

#include "infer/fmu/fmi2.h"
#include "infer/fmu/osi_model.h"

namespace {

namespace fs = std::filesystem;

enum : fmi2ValueReference { kInLo = 0, kInHi = 1, kInSize = 2, kOutLo = 3, kOutHi = 4, kOutSize = 5, kNumInts = 6 };
enum : fmi2ValueReference { kSensor = 6 };  // String parameter

struct Instance {
  std::string name;
  fmi2CallbackFunctions callbacks{};
  bool logging = false;
  fs::path resources;
  void* library = nullptr;
  lidarsim_osi_model_create_t* create = nullptr;
  lidarsim_osi_model_step_t* step = nullptr;
  lidarsim_osi_model_destroy_t* destroy = nullptr;
  void* model = nullptr;
  std::string sensor;        // the `sensor` parameter
  std::string model_sensor;  // the layout `model` was created with
  bool initialized = false;  // past fmi2ExitInitializationMode: parameters are fixed
  fmi2Integer ints[kNumInts] = {0, 0, 0, 0, 0, 0};
  long steps = 0;
  char error[1024] = {0};

  ~Instance() {
    if (model) destroy(model);
    if (library) dlclose(library);
  }

  // (Re)creates the model for the `sensor` parameter; false with the reason in `error`.
  bool create_model() {
    if (model) destroy(model);
    model = create(resources.c_str(), sensor.c_str(), error, sizeof error);
    model_sensor = sensor;
    return model != nullptr;
  }

  void log(fmi2Status status, const char* category, const std::string& message) const {
    if (callbacks.logger && (logging || status >= fmi2Warning))
      callbacks.logger(callbacks.componentEnvironment, name.c_str(), status, category, "%s", message.c_str());
  }
};

// "file:///a/b", "file:/a/b" or "file://localhost/a/b" with %XX escapes -> /a/b.
fs::path path_from_uri(const std::string& uri) {
  std::string p = uri;
  if (p.rfind("file://localhost/", 0) == 0) p = p.substr(16);
  else if (p.rfind("file:///", 0) == 0) p = p.substr(7);
  else if (p.rfind("file:/", 0) == 0) p = p.substr(5);
  std::string out;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (p[i] == '%' && i + 2 < p.size()) {
      out += static_cast<char>(std::stoi(p.substr(i + 1, 2), nullptr, 16));
      i += 2;
    } else {
      out += p[i];
    }
  }
  return out;
}

fs::path library_dir() {
  Dl_info info{};
  if (dladdr(reinterpret_cast<void*>(&path_from_uri), &info) && info.dli_fname)
    return fs::absolute(fs::path(info.dli_fname)).parent_path();
  return {};
}

fs::path find_resources(fmi2String location) {
  const auto has_models = [](const fs::path& d) { return !d.empty() && fs::exists(d / "kpi_pointrcnn.json"); };
  if (location && *location) {
    const fs::path p = path_from_uri(location);
    if (has_models(p)) return p;
  }
  const fs::path lib = library_dir();
  for (const fs::path& p : {lib / ".." / ".." / "resources", lib / "resources"})
    if (has_models(p)) return fs::canonical(p);
  return {};
}

Instance* as_instance(fmi2Component c) { return static_cast<Instance*>(c); }

}  // namespace

extern "C" {

#define LIDARSIM_FMI_EXPORT __attribute__((visibility("default")))

LIDARSIM_FMI_EXPORT const char* fmi2GetTypesPlatform() { return "default"; }
LIDARSIM_FMI_EXPORT const char* fmi2GetVersion() { return "2.0"; }

LIDARSIM_FMI_EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                                  fmi2String fmuResourceLocation,
                                                  const fmi2CallbackFunctions* functions, fmi2Boolean /*visible*/,
                                                  fmi2Boolean loggingOn) {
  auto inst = std::make_unique<Instance>();
  inst->name = instanceName ? instanceName : "lidarsim_osi";
  if (functions) inst->callbacks = *functions;
  inst->logging = loggingOn;
  if (fmuType != fmi2CoSimulation) {
    inst->log(fmi2Error, "FMI", "only Co-Simulation is supported");
    return nullptr;
  }
  if (fmuGUID && std::strcmp(fmuGUID, LIDARSIM_FMU_GUID) != 0) {
    inst->log(fmi2Error, "FMI", std::string("GUID ") + fmuGUID + " is not this FMU's (" + LIDARSIM_FMU_GUID + ")");
    return nullptr;
  }
  inst->resources = find_resources(fmuResourceLocation);
  if (inst->resources.empty()) {
    inst->log(fmi2Error, "FMI", "no resources folder with the model files (fmuResourceLocation: " +
                                    std::string(fmuResourceLocation ? fmuResourceLocation : "(none)") + ")");
    return nullptr;
  }
  const fs::path model_so = library_dir() / "lidarsim_osi_model.so";
  // RTLD_NODELETE: the model's OpenMP worker threads may outlive fmi2FreeInstance.
  inst->library = dlopen(model_so.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
  if (!inst->library) {
    inst->log(fmi2Error, "FMI", "cannot load " + model_so.string() + ": " + dlerror());
    return nullptr;
  }
  inst->create = reinterpret_cast<lidarsim_osi_model_create_t*>(dlsym(inst->library, "lidarsim_osi_model_create"));
  inst->step = reinterpret_cast<lidarsim_osi_model_step_t*>(dlsym(inst->library, "lidarsim_osi_model_step"));
  inst->destroy = reinterpret_cast<lidarsim_osi_model_destroy_t*>(dlsym(inst->library, "lidarsim_osi_model_destroy"));
  if (!inst->create || !inst->step || !inst->destroy) {
    inst->log(fmi2Error, "FMI", model_so.string() + " lacks the lidarsim_osi_model_* functions");
    return nullptr;
  }
  if (!inst->create_model()) {
    inst->log(fmi2Error, "FMI", std::string("loading the model: ") + inst->error);
    return nullptr;
  }
  inst->log(fmi2OK, "FMI", "model loaded from " + inst->resources.string());
  return inst.release();
}

LIDARSIM_FMI_EXPORT void fmi2FreeInstance(fmi2Component c) { delete as_instance(c); }

LIDARSIM_FMI_EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t, const fmi2String[]) {
  as_instance(c)->logging = on;
  return fmi2OK;
}

LIDARSIM_FMI_EXPORT fmi2Status fmi2SetupExperiment(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real, fmi2Boolean,
                                                   fmi2Real) {
  return fmi2OK;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component) { return fmi2OK; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
  Instance* inst = as_instance(c);
  inst->initialized = true;
  if (inst->sensor == inst->model_sensor) return fmi2OK;
  if (!inst->create_model()) {
    inst->log(fmi2Error, "FMI", std::string("loading the model for sensor \"") + inst->sensor + "\": " + inst->error);
    return fmi2Error;
  }
  inst->log(fmi2OK, "FMI", "sensor layout " + inst->sensor);
  return fmi2OK;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2Terminate(fmi2Component) { return fmi2OK; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2Reset(fmi2Component c) {
  // Tracking and KPI noise carry state: a reset is a fresh model.
  Instance* inst = as_instance(c);
  inst->sensor.clear();  // parameters back to their start values
  inst->initialized = false;
  if (!inst->create_model()) {
    inst->log(fmi2Error, "FMI", std::string("reset: ") + inst->error);
    return fmi2Error;
  }
  std::fill(std::begin(inst->ints), std::end(inst->ints), 0);
  inst->steps = 0;
  return fmi2OK;
}

LIDARSIM_FMI_EXPORT fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                              const fmi2Integer value[]) {
  Instance* inst = as_instance(c);
  for (size_t i = 0; i < nvr; ++i) {
    if (vr[i] > kInSize) {
      inst->log(fmi2Error, "FMI", "fmi2SetInteger: value reference " + std::to_string(vr[i]) + " is not an input");
      return fmi2Error;
    }
    inst->ints[vr[i]] = value[i];
  }
  return fmi2OK;
}

LIDARSIM_FMI_EXPORT fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                              fmi2Integer value[]) {
  Instance* inst = as_instance(c);
  for (size_t i = 0; i < nvr; ++i) {
    if (vr[i] >= kNumInts) {
      inst->log(fmi2Error, "FMI", "fmi2GetInteger: unknown value reference " + std::to_string(vr[i]));
      return fmi2Error;
    }
    value[i] = inst->ints[vr[i]];
  }
  return fmi2OK;
}

LIDARSIM_FMI_EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                                          fmi2Real communicationStepSize, fmi2Boolean) {
  Instance* inst = as_instance(c);
  const std::uintptr_t address = static_cast<std::uintptr_t>(static_cast<std::uint32_t>(inst->ints[kInLo])) |
                                 static_cast<std::uintptr_t>(static_cast<std::uint32_t>(inst->ints[kInHi])) << 32;
  const fmi2Integer size = inst->ints[kInSize];
  if (address == 0 || size <= 0) {  // OSMP: no input buffer this step, so no output either
    inst->ints[kOutLo] = inst->ints[kOutHi] = inst->ints[kOutSize] = 0;
    return fmi2OK;
  }
  const void* out = nullptr;
  int out_size = 0;
  if (inst->step(inst->model, reinterpret_cast<const void*>(address), size, &out, &out_size, inst->error,
                 sizeof inst->error) != 0) {
    inst->log(fmi2Error, "OSI", std::string(inst->error) + " (t = " + std::to_string(currentCommunicationPoint) + " s)");
    return fmi2Error;
  }
  const auto out_address = reinterpret_cast<std::uintptr_t>(out);
  inst->ints[kOutLo] = static_cast<fmi2Integer>(static_cast<std::uint32_t>(out_address & 0xffffffffu));
  inst->ints[kOutHi] = static_cast<fmi2Integer>(static_cast<std::uint32_t>(static_cast<std::uint64_t>(out_address) >> 32));
  inst->ints[kOutSize] = out_size;
  ++inst->steps;
  inst->log(fmi2OK, "OSI",
            "step " + std::to_string(inst->steps) + " to t = " +
                std::to_string(currentCommunicationPoint + communicationStepSize) + " s: " +
                std::to_string(out_size) + " bytes of SensorData");
  return fmi2OK;
}

// What this model does not have: no Real, Boolean or String variables, no FMU state, no derivatives.
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetReal(fmi2Component, const fmi2ValueReference[], size_t nvr, fmi2Real[]) {
  return nvr == 0 ? fmi2OK : fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetBoolean(fmi2Component, const fmi2ValueReference[], size_t nvr, fmi2Boolean[]) {
  return nvr == 0 ? fmi2OK : fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                             fmi2String value[]) {
  Instance* inst = as_instance(c);
  for (size_t i = 0; i < nvr; ++i) {
    if (vr[i] != kSensor) {
      inst->log(fmi2Error, "FMI", "fmi2GetString: unknown value reference " + std::to_string(vr[i]));
      return fmi2Error;
    }
    value[i] = inst->sensor.c_str();
  }
  return fmi2OK;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2SetReal(fmi2Component, const fmi2ValueReference[], size_t nvr, const fmi2Real[]) {
  return nvr == 0 ? fmi2OK : fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2SetBoolean(fmi2Component, const fmi2ValueReference[], size_t nvr,
                                              const fmi2Boolean[]) {
  return nvr == 0 ? fmi2OK : fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                             const fmi2String value[]) {
  Instance* inst = as_instance(c);
  for (size_t i = 0; i < nvr; ++i) {
    if (vr[i] != kSensor) {
      inst->log(fmi2Error, "FMI", "fmi2SetString: value reference " + std::to_string(vr[i]) + " is not a parameter");
      return fmi2Error;
    }
    if (inst->initialized) {
      inst->log(fmi2Error, "FMI", "fmi2SetString: sensor is fixed after initialization");
      return fmi2Error;
    }
    inst->sensor = value[i] ? value[i] : "";
  }
  return fmi2OK;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetFMUstate(fmi2Component, fmi2FMUstate*) { return fmi2Error; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2SetFMUstate(fmi2Component, fmi2FMUstate) { return fmi2Error; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component, fmi2FMUstate*) { return fmi2Error; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component, fmi2FMUstate, size_t*) { return fmi2Error; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component, fmi2FMUstate, fmi2Byte[], size_t) {
  return fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component, const fmi2Byte[], size_t, fmi2FMUstate*) {
  return fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component, const fmi2ValueReference[], size_t,
                                                            const fmi2ValueReference[], size_t, const fmi2Real[],
                                                            fmi2Real[]) {
  return fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component, const fmi2ValueReference[], size_t,
                                                           const fmi2Integer[], const fmi2Real[]) {
  return fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component, const fmi2ValueReference[], size_t,
                                                            const fmi2Integer[], fmi2Real[]) {
  return fmi2Error;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2CancelStep(fmi2Component) { return fmi2Error; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetStatus(fmi2Component, const fmi2StatusKind, fmi2Status*) { return fmi2Discard; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetRealStatus(fmi2Component, const fmi2StatusKind, fmi2Real*) { return fmi2Discard; }
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component, const fmi2StatusKind, fmi2Integer*) {
  return fmi2Discard;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component, const fmi2StatusKind, fmi2Boolean*) {
  return fmi2Discard;
}
LIDARSIM_FMI_EXPORT fmi2Status fmi2GetStringStatus(fmi2Component, const fmi2StatusKind, fmi2String*) {
  return fmi2Discard;
}

}  // extern "C"
