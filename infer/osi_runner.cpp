#include "infer/osi_runner.h"

#include <cmath>

#include "common/error.h"

namespace lidarsim::infer {

void make_ideal(SimOptions& options) {
  options.kpi.noise = options.kpi.misses = options.kpi.false_positives = options.kpi.flips = false;
  options.tracker.confirm_hits = 1;
}

OsiRunner::OsiRunner(sensor::SensorSpec sensor, sensor::KpiModel kpi, std::unique_ptr<IntensityModel> intensity,
                     SimOptions options)
    : sensor_(std::move(sensor)), kpi_(std::move(kpi)), intensity_(std::move(intensity)), options_(options) {
  if (!options_.point_cloud) options_.intensity = false;
  if (options_.intensity && !intensity_) throw Error("osi runner: an intensity model is required");
}

void OsiRunner::step(const osi3::SensorView& in, long index, const std::string& source, osi3::SensorData& out) {
  auto fail = [&](const std::string& field, const std::string& what) {
    return Error(source + ": message " + std::to_string(index) + ": " + field + ": " + what);
  };
  osi::scene_from_sensor_view(in, index, source, ids_, scene_);
  if (!pipeline_) {
    sensor::Scenario s;
    s.name = "osi";
    s.source = source;
    s.duration = 0;
    s.sensor = sensor_;
    s.sensor.mount = scene_.mount;
    pipeline_.emplace(std::move(s), std::move(*kpi_), std::move(intensity_), options_);
    kpi_.reset();
  } else {
    const sensor::Pose& first = pipeline_->scenario().sensor.mount;
    if ((first.translation - scene_.mount.translation).norm() > 1e-3 ||
        (first.rotation - scene_.mount.rotation).norm() > 1e-4)
      throw fail("mounting_position", "differs from the first message's (the sensor is built for one mount)");
    if (!(scene_.time > last_time_))
      throw fail("timestamp", "does not advance (" + std::to_string(scene_.time) + " s after " +
                                  std::to_string(last_time_) + " s)");
  }
  last_time_ = scene_.time;
  pipeline_->run_ground_truth(static_cast<int>(frames_), scene_.map, frame_);

  detections_.resize(frame_.reported.size());
  for (std::size_t i = 0; i < frame_.reported.size(); ++i) {
    detections_[i].object = frame_.reported[i].object;
    detections_[i].truth_id = frame_.reported[i].truth_id;
    detections_[i].coasting = frame_.reported[i].coasting;
  }
  const SimCloud& c = frame_.cloud;
  osi::CloudRef cloud;
  cloud.size = c.size();
  cloud.range = c.range.data();
  cloud.intensity = c.intensity.data();
  cloud.object_id = c.object_id.data();
  cloud.cell = c.cell.data();
  cloud.layout = &frame_.pgm.layout();
  osi::build_sensor_data(scene_, detections_, frame_.lanes, cloud, ids_, static_cast<std::uint64_t>(frames_), out);
  ++frames_;
}

}  // namespace lidarsim::infer
