#pragma once
// `lidar-infer osi` (a SensorView trace through the sensor model into a SensorData trace, from a
// file or stdin, to a file or stdout) and `lidar-infer osi-trace` (a scenario JSON as a SensorView
// trace). `resolve` finds a bundled default (data/...) like the other commands do.
#include <filesystem>
#include <functional>
#include <string>

namespace lidarsim::infer {

using DefaultResolver = std::function<std::filesystem::path(const std::string&)>;

int run_osi_command(int argc, char** argv, const DefaultResolver& resolve);
int run_osi_trace_command(int argc, char** argv, const DefaultResolver& resolve);

}  // namespace lidarsim::infer
