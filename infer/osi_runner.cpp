#include "infer/osi_runner.h"

#include <chrono>
#include <cmath>

#include "common/error.h"

namespace lidarsim::infer {

void make_ideal(SimOptions& options) {
  options.kpi.noise = options.kpi.misses = options.kpi.false_positives = options.kpi.flips = false;
  options.tracker.confirm_hits = 1;
}

namespace {

bool same_pose(const sensor::Pose& a, const sensor::Pose& b) {
  return (a.translation - b.translation).norm() <= 1e-3 && (a.rotation - b.rotation).norm() <= 1e-4;
}

osi::CloudRef cloud_of(const SimFrame& f) {
  osi::CloudRef cloud;
  cloud.size = f.cloud.size();
  cloud.range = f.cloud.range.data();
  cloud.intensity = f.cloud.intensity.data();
  cloud.object_id = f.cloud.object_id.data();
  cloud.cell = f.cloud.cell.data();
  cloud.layout = &f.pgm.layout();
  return cloud;
}

using StepClock = std::chrono::steady_clock;
double ms_since(StepClock::time_point t0) {
  return std::chrono::duration<double, std::milli>(StepClock::now() - t0).count();
}

}  // namespace

OsiRunner::OsiRunner(sensor::SensorSpec sensor, sensor::KpiModel kpi, std::unique_ptr<IntensityModel> intensity,
                     SimOptions options, IntensityLoader loader)
    : sensor_(std::move(sensor)),
      kpi_(kpi),
      intensity_(std::move(intensity)),
      options_(options),
      loader_(std::move(loader)),
      kpi_spare_(std::move(kpi)) {
  if (!options_.point_cloud) options_.intensity = false;
  if (options_.intensity && !intensity_) throw Error("osi runner: an intensity model is required");
}

void OsiRunner::step(const osi::msg::SensorView& in, long index, const std::string& source, std::string& out,
                     std::size_t prefix) {
  advance(in, index, source);
  const auto t0 = StepClock::now();
  osi::encode_sensor_data(scene_, detections_, frame_.lanes, clouds_, ids_, static_cast<std::uint64_t>(frames_), out,
                          prefix);
  times_.output_ms = ms_since(t0);
  ++frames_;
}

std::size_t OsiRunner::reported_points() const {
  std::size_t n = 0;
  for (const auto& c : clouds_) n += c.size;
  return n;
}

void OsiRunner::advance(const osi::msg::SensorView& in, long index, const std::string& source) {
  auto fail = [&](const std::string& field, const std::string& what) {
    return Error(source + ": message " + std::to_string(index) + ": " + field + ": " + what);
  };
  auto t0 = StepClock::now();
  osi::scene_from_sensor_view(in, index, source, ids_, scene_);
  times_.scene_ms = ms_since(t0);
  if (!pipeline_) {
    build(source, index);
  } else {
    if (!same_pose(pipeline_->scenario().sensor.mount, scene_.mount))
      throw fail("mounting_position", "differs from the first message's (the sensor is built for one mount)");
    if (scene_.detectors.size() != detector_mounts_.size())
      throw fail("lidar_sensor_view", std::to_string(scene_.detectors.size()) + " detectors, the first message had " +
                                          std::to_string(detector_mounts_.size()));
    for (std::size_t i = 0; i < detector_mounts_.size(); ++i)
      if (!same_pose(detector_mounts_[i], scene_.detectors[i].mount))
        throw fail("lidar_sensor_view[" + std::to_string(i) + "].view_configuration.mounting_position",
                   "differs from the first message's (each detector is built for one mount)");
    if (!(scene_.time > last_time_))
      throw fail("timestamp", "does not advance (" + std::to_string(scene_.time) + " s after " +
                                  std::to_string(last_time_) + " s)");
  }
  last_time_ = scene_.time;
  t0 = StepClock::now();
  pipeline_->run_ground_truth(static_cast<int>(frames_), scene_.map, frame_);
  for (auto& o : own_) o->pipeline.run_ground_truth(static_cast<int>(frames_), scene_.map, o->frame);

  detections_.resize(frame_.reported.size());
  for (std::size_t i = 0; i < frame_.reported.size(); ++i) {
    detections_[i].object = frame_.reported[i].object;
    detections_[i].truth_id = frame_.reported[i].truth_id;
    detections_[i].coasting = frame_.reported[i].coasting;
  }
  clouds_.clear();
  for (int k : cloud_of_) {
    const SimFrame& f = k < 0 ? frame_ : own_[static_cast<std::size_t>(k)]->frame;
    clouds_.push_back(options_.point_cloud ? cloud_of(f) : osi::CloudRef{});
  }
  times_.model_ms = ms_since(t0);
}

// The pipelines, on the first message: the virtual sensor's, and one per detector at a mount of
// its own (only with the point cloud: without it detectors report no features).
void OsiRunner::build(const std::string& source, long index) {
  const auto scenario_at = [&](const sensor::Pose& mount) {
    sensor::Scenario s;
    s.name = "osi";
    s.source = source;
    s.duration = 0;
    s.sensor = sensor_;
    s.sensor.mount = mount;
    return s;
  };
  cloud_of_.clear();
  detector_mounts_.clear();
  std::vector<std::unique_ptr<OwnMount>> own;
  for (std::size_t i = 0; i < scene_.detectors.size(); ++i) {
    const sensor::Pose& mount = scene_.detectors[i].mount;
    detector_mounts_.push_back(mount);
    if (!options_.point_cloud || same_pose(mount, scene_.mount)) {
      cloud_of_.push_back(-1);
      continue;
    }
    std::unique_ptr<IntensityModel> m;
    if (options_.intensity) {
      if (!loader_)
        throw Error(source + ": message " + std::to_string(index) + ": lidar_sensor_view[" + std::to_string(i) +
                    "].view_configuration.mounting_position: a detector away from the virtual mount needs an "
                    "intensity model of its own, and this runner has no loader");
      m = loader_();
    }
    cloud_of_.push_back(static_cast<int>(own.size()));
    own.push_back(std::make_unique<OwnMount>(
        OwnMount{SimPipeline(scenario_at(mount), kpi_spare_, std::move(m), options_), SimFrame{}}));
  }
  pipeline_.emplace(scenario_at(scene_.mount), std::move(*kpi_), std::move(intensity_), options_);
  kpi_.reset();
  own_ = std::move(own);
}

}  // namespace lidarsim::infer
