#pragma once
// The C interface between the FMU's entry library (osmp_sensor.cpp, lidarsim_osi.so) and the
// model library (osi_model.cpp, lidarsim_osi_model.so). Only serialized bytes cross it, so the
// model can carry the schema under a package name of its own (infer/fmu/CMakeLists.txt): an
// importer that has the official OSI messages registered in its libprotobuf cannot clash with it.
#include <cstddef>

extern "C" {

// Loads sensor.json, kpi_pointrcnn.json and intensity_unet.weights from `resources_dir`; null on
// failure with the reason in `error`. `sensor_layout`, when not empty, names the beam layout that
// replaces sensor.json's beams: a file of resources/sensors/ without ".json" (the bundled
// data/sensors/ layouts) or a path to a layout JSON. Each model is independent of the others:
// several may run at once in different threads (one per lidar of a car).
typedef void* lidarsim_osi_model_create_t(const char* resources_dir, const char* sensor_layout, char* error,
                                          std::size_t error_size);
// One osi3.SensorView (serialized) -> one osi3.SensorData (serialized, owned by the model and
// valid until the second call after this one). 0 on success, else the reason in `error`.
typedef int lidarsim_osi_model_step_t(void* model, const void* in, int in_size, const void** out, int* out_size,
                                      char* error, std::size_t error_size);
typedef void lidarsim_osi_model_destroy_t(void* model);

}  // extern "C"
