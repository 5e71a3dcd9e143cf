// The OsiRunner steps that take or give libprotobuf messages (infer/osi_runner.h). Kept apart from
// osi_runner.cpp so that the FMU, which steps on decoded bytes, links no libprotobuf.
#include <chrono>

#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"

namespace lidarsim::infer {

void OsiRunner::step(const osi::msg::SensorView& in, long index, const std::string& source, osi3::SensorData& out) {
  advance(in, index, source);
  const auto t0 = std::chrono::steady_clock::now();
  osi::build_sensor_data(scene_, detections_, frame_.lanes, clouds_, ids_, static_cast<std::uint64_t>(frames_), out);
  times_.output_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  ++frames_;
}

void OsiRunner::step(const osi3::SensorView& in, long index, const std::string& source, osi3::SensorData& out) {
  step(osi::decoded(in), index, source, out);
}

void OsiRunner::step(const osi3::SensorView& in, long index, const std::string& source, std::string& out,
                     std::size_t prefix) {
  step(osi::decoded(in), index, source, out, prefix);
}

void OsiRunner::last_sensor_data(osi3::SensorData& out) const {
  if (frames_ == 0) throw Error("osi runner: no frame yet");
  osi::build_sensor_data(scene_, detections_, frame_.lanes, clouds_, ids_, static_cast<std::uint64_t>(frames_ - 1), out);
}

}  // namespace lidarsim::infer
