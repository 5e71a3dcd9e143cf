// The model behind the OSMP FMU: OsiRunner (the same as `lidar-infer osi`) with OSMP's double
// buffered output. Exported as a C interface (osi_model.h); loaded by osmp_sensor.cpp.
#include "infer/fmu/osi_model.h"

#include <cstdio>
#include <exception>
#include <filesystem>
#include <memory>
#include <string>

#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/sensor_view_decoder.h"

namespace {

struct Model {
  std::unique_ptr<lidarsim::infer::OsiRunner> runner;
  lidarsim::osi::msg::SensorView view;  // decoded by hand: this library links no libprotobuf
  std::string out[2];  // OSMP: the previous output stays valid while the next one is computed
  int current = 0;
  long steps = 0;
};

// The `sensor` parameter: a bundled layout's name (resources/sensors/NAME.json) or a layout file.
std::filesystem::path layout_path(const std::filesystem::path& resources, const std::string& sensor) {
  namespace fs = std::filesystem;
  if (sensor.find('/') != std::string::npos || fs::path(sensor).extension() == ".json") return sensor;
  const fs::path p = resources / "sensors" / (sensor + ".json");
  if (fs::exists(p)) return p;
  std::string names;
  if (fs::is_directory(resources / "sensors"))
    for (const auto& e : fs::directory_iterator(resources / "sensors"))
      if (e.path().extension() == ".json") names += (names.empty() ? "" : ", ") + e.path().stem().string();
  throw lidarsim::Error("sensor: no layout \"" + sensor + "\" in " + (resources / "sensors").string() +
                        " (bundled: " + names + "; or give a path to a layout .json)");
}

void set_error(char* error, std::size_t size, const std::string& what) {
  if (error && size > 0) std::snprintf(error, size, "%s", what.c_str());
}

}  // namespace

extern "C" {

__attribute__((visibility("default"))) void* lidarsim_osi_model_create(const char* resources_dir,
                                                                         const char* sensor_layout, char* error,
                                                                         std::size_t error_size) {
  try {
    const std::filesystem::path r = resources_dir;
    auto m = std::make_unique<Model>();
    lidarsim::sensor::Scenario scenario = lidarsim::sensor::read_scenario(r / "sensor.json");
    if (sensor_layout && *sensor_layout)
      lidarsim::infer::use_sensor(scenario,
                                  lidarsim::pgm::BeamLayout::from_file(layout_path(r, sensor_layout).string()));
    // The UNet as a weights file (nn/checkpoint_weights.h), so this library links no HDF5.
    using lidarsim::infer::IntensityModel;
    m->runner = std::make_unique<lidarsim::infer::OsiRunner>(
        scenario.sensor,
        lidarsim::sensor::load_kpi_model(r / "kpi_pointrcnn.json"),
        std::make_unique<IntensityModel>(IntensityModel::load_weights(r / "intensity_unet.weights")),
        lidarsim::infer::SimOptions{},
        [r] { return std::make_unique<IntensityModel>(IntensityModel::load_weights(r / "intensity_unet.weights")); });
    return m.release();
  } catch (const std::exception& e) {
    set_error(error, error_size, e.what());
    return nullptr;
  }
}

__attribute__((visibility("default"))) int lidarsim_osi_model_step(void* model, const void* in, int in_size,
                                                                   const void** out, int* out_size, char* error,
                                                                   std::size_t error_size) {
  Model& m = *static_cast<Model*>(model);
  try {
    if (in_size < 0 || (in_size > 0 && !in)) throw lidarsim::Error("OSMPSensorViewIn: no message");
    lidarsim::osi::decode_sensor_view(std::string_view(static_cast<const char*>(in), static_cast<std::size_t>(in_size)),
                                      "OSMPSensorViewIn", m.steps, m.view);
    // Encoded straight into the buffer (osi::encode_sensor_data), which keeps its capacity.
    std::string& buffer = m.out[m.current ^ 1];
    m.runner->step(m.view, m.steps, "OSMPSensorViewIn", buffer);
    m.current ^= 1;
    *out = buffer.data();
    *out_size = static_cast<int>(buffer.size());
    ++m.steps;
    return 0;
  } catch (const std::exception& e) {
    set_error(error, error_size, e.what());
    return 1;
  }
}

__attribute__((visibility("default"))) void lidarsim_osi_model_destroy(void* model) {
  delete static_cast<Model*>(model);
}

}  // extern "C"
