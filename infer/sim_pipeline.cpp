#include "infer/sim_pipeline.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>

#include "common/error.h"
#include "nn/unet.h"
#include "pgm/encoder.h"
#include "sensor/fov.h"
#include "sensor/frames.h"
#include "sensor/lanes.h"
#include "sensor/scenery.h"

namespace lidarsim::infer {

const char* to_string(SimStage s) {
  switch (s) {
    case SimStage::Sample: return "sample";
    case SimStage::Frames: return "frames";
    case SimStage::FieldOfView: return "fov";
    case SimStage::Occlusion: return "occlusion";
    case SimStage::Tracking: return "tracking";
    case SimStage::Kpi: return "kpi";
    case SimStage::Lanes: return "lanes";
    case SimStage::PclGenerator: return "pcl_generator";
    case SimStage::Unet: return "unet";
    case SimStage::PointCloud: return "point_cloud";
  }
  return "?";
}

void SimCloud::clear() {
  for (auto* v : {&x, &y, &z, &intensity, &cls, &material, &object_id, &range}) v->clear();
  cell.clear();
}

namespace {

sensor::PclConfig pcl_config(const sensor::Scenario& s, const SimOptions& options) {
  sensor::PclConfig c;
  c.min_range = s.sensor.fov.range_min;
  c.max_range = s.sensor.fov.range_max;
  c.range_noise = options.range_noise;
  c.range_noise_seed = options.seed;
  c.returns = options.returns;
  c.return_seed = options.seed;
  return c;
}

}  // namespace

SimPipeline::SimPipeline(sensor::Scenario scenario, sensor::KpiModel kpi_model,
                         std::unique_ptr<IntensityModel> intensity, SimOptions options)
    : scenario_(std::move(scenario)),
      intensity_(std::move(intensity)),
      options_(options),
      tracker_(options.tracker),
      kpi_(std::move(kpi_model), options.seed, options.kpi),
      // Occlusion on the sensor's own angular grid (one cell per azimuth bin): finer cells
      // cost time without changing what the beams can see.
      occlusion_(sensor::OcclusionConfig::for_fov(scenario_.sensor.fov,
                                                  2 * std::numbers::pi / scenario_.sensor.beams.columns)),
      pcl_(scenario_.sensor.beams.layout(), scenario_.sensor.mount, pcl_config(scenario_, options)) {
  if (!options_.point_cloud) options_.intensity = false;
  if (options_.intensity && !intensity_) throw Error("sim pipeline: an intensity model is required");
  if (intensity_) extra_channels_ = intensity_->extra_channels();
  if (options_.sample_intensity && options_.intensity)
    intensity_->sample_from_spread({options_.seed}, "sim pipeline: --sample-intensity");
  if (!options_.spread_terms.empty()) {
    if (!options_.sample_intensity) throw Error("sim pipeline: --spread-terms needs --sample-intensity (the mean has no spread)");
    if (intensity_) intensity_->set_spread_terms(options_.spread_terms);
  }
  // Generous first reservations, so the first frames do not grow buffers piecemeal.
  detections_.reserve(64);
  tracked_.reserve(64);
  kpi_out_.reserve(64);
  pcl_objects_.reserve(64);
}

void use_sensor(sensor::Scenario& scenario, const pgm::BeamLayout& layout) {
  layout.validate("sensor layout");
  auto& spec = scenario.sensor;
  spec.beams.kind = "layout";
  spec.beams.full = layout;
  spec.beams.columns = layout.columns;
  // Half a beam spacing beyond the outer beams, so the outer rows stay inside the field of view.
  const int n = layout.rows();
  const double margin = n > 1 ? 0.5 * (layout.elevations_rad[0] - layout.elevations_rad[n - 1]) / (n - 1) : 0.01;
  spec.fov.elevation_max = layout.elevations_rad[0] + margin;
  spec.fov.elevation_min = layout.elevations_rad[n - 1] - margin;
  if (layout.max_range_m > 0) spec.fov.range_max = layout.max_range_m;
  if (layout.min_range_m > 0) spec.fov.range_min = layout.min_range_m;
}

void SimPipeline::run_frame(int k, SimFrame& out, bool intensity) {
  const auto start = std::chrono::steady_clock::now();
  sensor::sample_frame(scenario_, scenario_.frame_time(k), map_frame_, &cursor_);
  run_stages(k, map_frame_, start, out, intensity);
}

void SimPipeline::run_ground_truth(int k, const sensor::Frame& map_frame, SimFrame& out) {
  run_stages(k, map_frame, std::chrono::steady_clock::now(), out);
}

void SimPipeline::run_stages(int k, const sensor::Frame& map_frame, std::chrono::steady_clock::time_point start,
                             SimFrame& out, bool intensity_wanted) {
  using clock = std::chrono::steady_clock;
  auto mark = start;
  auto lap = [&](SimStage s) {
    const auto now = clock::now();
    out.stage_ms[static_cast<int>(s)] = std::chrono::duration<double, std::milli>(now - mark).count();
    mark = now;
  };
  out.stage_ms.fill(0);
  out.intensity_skipped = false;
  out.index = k;
  out.time = map_frame.time;
  out.objects_existing = static_cast<int>(map_frame.objects.size());
  lap(SimStage::Sample);

  sensor::map_to_ego(map_frame, out.ego);
  sensor::ego_to_sensor(out.ego, scenario_.sensor.mount, out.sensor);
  lap(SimStage::Frames);

  sensor::apply_fov(out.sensor.objects, scenario_.sensor.fov, &heading_trig_);
  sensor::apply_fov_to_lanes(out.sensor.lanes, scenario_.sensor.fov);
  sensor::cull_scenery(out.sensor.scenery, scenario_.sensor.fov.range_max);
  out.objects_in_view = static_cast<int>(out.sensor.objects.size());
  lap(SimStage::FieldOfView);

  occlude(out);
  lap(SimStage::Occlusion);

  const sensor::Pose map_from_sensor = sensor::compose(out.ego.ego_in_map, scenario_.sensor.mount);
  track(out, map_from_sensor);
  lap(SimStage::Tracking);

  report(out, map_from_sensor);
  lap(SimStage::Kpi);

  sensor::fit_lanes(out.sensor.lanes, out.lanes);
  lap(SimStage::Lanes);

  if (options_.point_cloud) {
    const bool predict = options_.intensity && intensity_wanted;
    generate_returns(k, out, predict);
    lap(SimStage::PclGenerator);

    out.intensity_skipped = options_.intensity && !intensity_wanted;
    if (predict) predict_intensity(k, out);
    lap(SimStage::Unet);

    fill_cloud(out);
    lap(SimStage::PointCloud);
  } else {
    out.returns = 0;
    out.cloud.clear();
  }
  out.total_ms = 0;
  for (double ms : out.stage_ms) out.total_ms += ms;
}

void SimPipeline::occlude(SimFrame& out) {
  occlusion_.apply(out.sensor.objects, out.sensor.lanes, out.sensor.scenery, &heading_trig_);
  out.objects_occluded = out.objects_partly_occluded = 0;
  for (const auto& o : out.sensor.objects) {
    if (o.visible_fraction <= 0) ++out.objects_occluded;
    else if (o.visible_fraction < 1) ++out.objects_partly_occluded;
  }
  // Folded as KITTI's labels are (data/kitti_tracking.cpp): the KPI model's visibility bins were fitted on that.
  for (auto& o : out.sensor.objects) o.visible_fraction *= 1 - o.truncation;
}

// Tracking runs in the map frame, so the filter's velocity is over ground like the ground truth's
// (in the moving sensor frame it would estimate velocity relative to the ego); the tracks go back
// into the sensor frame for the KPI manager (range, line of sight) and output. A fully hidden
// object yields no measurement: its track coasts.
void SimPipeline::track(const SimFrame& out, const sensor::Pose& map_from_sensor) {
  const sensor::Pose sensor_from_map = sensor::inverse(map_from_sensor);
  detections_.clear();
  for (std::size_t i = 0; i < out.sensor.objects.size(); ++i) {
    const sensor::Object& o = out.sensor.objects[i];
    if (o.visible_fraction > 0) {
      detections_.emplace_back();
      sensor::transform_object(map_from_sensor, o, detections_.back(), &heading_trig_[i]);
    }
  }
  tracker_.update(detections_, out.time);
  tracker_.reported(tracked_map_);
  tracked_.resize(tracked_map_.size());
  for (std::size_t i = 0; i < tracked_map_.size(); ++i) sensor::transform_object(sensor_from_map, tracked_map_[i], tracked_[i]);
}

void SimPipeline::report(SimFrame& out, const sensor::Pose& map_from_sensor) {
  if (last_map_from_sensor_) {
    const sensor::Pose step = sensor::compose(sensor::inverse(*last_map_from_sensor_), map_from_sensor);
    kpi_.set_ego_motion(step.translation.head<2>(), std::atan2(step.rotation(1, 0), step.rotation(0, 0)));
  }
  last_map_from_sensor_ = map_from_sensor;
  kpi_.apply(tracked_, kpi_out_);
  out.reported.resize(kpi_out_.size());
  // The track of each reported object (ids are unique): the KPI manager keeps the tracks' order,
  // so the search goes on from the last track found and wraps round only for a false positive.
  const auto& tracks = tracker_.tracks();
  const std::size_t nt = tracks.size();
  std::size_t next = 0;
  for (std::size_t i = 0; i < kpi_out_.size(); ++i) {
    ReportedObject& r = out.reported[i];
    r.object = kpi_out_[i];
    r.truth_id = -1;
    r.coasting = false;
    for (std::size_t n = 0; n < nt; ++n) {
      const std::size_t j = next + n < nt ? next + n : next + n - nt;
      if (tracks[j].id == r.object.id) {
        r.truth_id = tracks[j].source_id;
        r.coasting = tracks[j].state == sensor::TrackState::Coasting;
        next = j + 1 < nt ? j + 1 : 0;
        break;
      }
    }
  }
}

void SimPipeline::generate_returns(int k, SimFrame& out, bool predict) {
  if (out.pgm.rows() != pcl_.layout().rows() || out.pgm.cols() != pcl_.layout().columns)
    out.pgm = pcl_.make_map(extra_channels_);
  sensor::select_visible(out.ego.objects, out.sensor.objects, pcl_objects_);
  // Paint exists whether or not the lane model reports it: the rays decide what is seen.
  // Without the UNet on this frame its neighbourhood input channels are not needed either.
  pcl_.set_frame(static_cast<std::uint64_t>(k));  // range noise and return draws follow the frame, not the call count
  out.returns = pcl_.generate(pcl_objects_, out.ego.scenery, out.ego.lanes, out.pgm, predict || !options_.intensity);
}

// The intensity channel holds 0 from the PCL generator until the UNet fills it.
void SimPipeline::predict_intensity(int k, SimFrame& out) {
  float* intensity = out.pgm.channel("intensity");
  intensity_->predict(out.pgm, predicted_, static_cast<std::uint64_t>(k));
  const float* mask = out.pgm.channel("mask");
  // The network is not bounded: keep the reflectivity it predicts in [0, 1] like KITTI's.
  for (std::size_t i = 0; i < out.pgm.cells(); ++i) intensity[i] = mask[i] > 0 ? std::clamp(predicted_[i], 0.f, 1.f) : 0.f;
}

// One point per cell with a return: sized once from the count, then filled by index.
void SimPipeline::fill_cloud(SimFrame& out) {
  SimCloud& c = out.cloud;
  const auto& layout = pcl_.layout();
  const int H = layout.rows(), W = layout.columns;
  const float* range = out.pgm.channel("range");
  const float* mask = out.pgm.channel("mask");
  const float* intensity = out.pgm.channel("intensity");
  const float* cls = out.pgm.channel("class");
  const float* material = out.pgm.channel("material");
  const float* object_id = out.pgm.channel("object_id");
  if (column_cos_.size() != static_cast<std::size_t>(W)) {  // cos / sin of each column's azimuth, once
    column_cos_.resize(W);
    column_sin_.resize(W);
    for (int col = 0; col < W; ++col) {
      const double az = layout.azimuth_of_column(col);
      column_cos_[col] = std::cos(az);
      column_sin_[col] = std::sin(az);
    }
  }
  std::size_t points = 0;
  for (std::size_t i = 0; i < out.pgm.cells(); ++i) points += mask[i] > 0;
  for (auto* v : {&c.x, &c.y, &c.z, &c.intensity, &c.cls, &c.material, &c.object_id, &c.range}) v->resize(points);
  c.cell.resize(points);
  std::size_t n = 0;
  for (int r = 0; r < H; ++r) {
    const double el = layout.elevations_rad[r];
    const double ce = std::cos(el), se = std::sin(el);
    for (int col = 0; col < W; ++col) {
      const int i = r * W + col;
      if (mask[i] <= 0) continue;
      const double rg = range[i];
      c.x[n] = static_cast<float>(rg * ce * column_cos_[col]);
      c.y[n] = static_cast<float>(rg * ce * column_sin_[col]);
      c.z[n] = static_cast<float>(rg * se);
      c.intensity[n] = intensity[i];
      c.cls[n] = cls[i];
      c.material[n] = material[i];
      c.object_id[n] = object_id[i];
      c.range[n] = range[i];
      c.cell[n] = i;
      ++n;
    }
  }
}

bool SimPipeline::kpi_model_has_persistence() const {
  for (const auto& [name, cm] : kpi_.model().classes)
    if (cm.fp_persistence.present()) return true;
  return false;
}

}  // namespace lidarsim::infer
