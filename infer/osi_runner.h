#pragma once
// The sensor model behind the OSI interface: osi3.SensorView in, osi3.SensorData out, one frame
// at a time, through the same pipeline as `lidar-infer sim` (frames, field of view, occlusion,
// tracking, KPI manager, lanes, PCL generator, PGM, UNet intensity). Shared by `lidar-infer osi`
// and the OSMP FMU (infer/fmu).
//
// The sensor's beams, field of view and range come from a scenario file's "sensor" block (the
// bundled demo's by default); its mount is replaced by the SensorView's mounting_position. The
// pipeline is built on the first SensorView, so the mount must not change during a run.
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "infer/intensity_model.h"
#include "infer/sim_pipeline.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"

namespace lidarsim::infer {

// `--ideal`: a model perfect by request. The KPI manager's errors, misses, false positives and
// heading flips off, and a track is confirmed on its first detection, so frame 0 already reports
// every visible object (its velocity and acceleration the ground truth's: a new track starts from
// the detection). Tracking and occlusion stay.
void make_ideal(SimOptions& options);

class OsiRunner {
 public:
  // intensity may be null when options.intensity is false.
  OsiRunner(sensor::SensorSpec sensor, sensor::KpiModel kpi, std::unique_ptr<IntensityModel> intensity,
            SimOptions options = {});
  // The sensor block of `scenario`, the KPI model and the intensity checkpoint (HDF5 or weights
  // file, IntensityModel::load); errors name the file. Inline, so that only its callers link the
  // HDF5 reader: the FMU's model library builds its runner with IntensityModel::load_weights.
  static OsiRunner from_files(const std::filesystem::path& scenario, const std::filesystem::path& kpi_model,
                              const std::filesystem::path& intensity_checkpoint, SimOptions options = {}) {
    sensor::Scenario s = sensor::read_scenario(scenario);
    sensor::KpiModel k = sensor::load_kpi_model(kpi_model);
    std::unique_ptr<IntensityModel> m;
    if (options.intensity && options.point_cloud)
      m = std::make_unique<IntensityModel>(IntensityModel::load(intensity_checkpoint));
    return OsiRunner(s.sensor, std::move(k), std::move(m), options);
  }

  // One frame. Bad input throws lidarsim::Error "<source>: message <index>: <field>: <what>"
  // (see osi::scene_from_sensor_view; also a mount that changes or a timestamp that does not advance).
  void step(const osi3::SensorView& in, long index, const std::string& source, osi3::SensorData& out);

  const SimFrame& last_frame() const { return frame_; }
  long frames() const { return frames_; }
  const sensor::SensorSpec& sensor() const { return sensor_; }
  const IntensityModel* intensity_model() const { return intensity_ ? intensity_.get() : nullptr; }

 private:
  sensor::SensorSpec sensor_;
  std::optional<sensor::KpiModel> kpi_;               // moved into the pipeline on the first frame
  std::unique_ptr<IntensityModel> intensity_;         // idem
  SimOptions options_;
  std::optional<SimPipeline> pipeline_;
  osi::IdMap ids_;
  osi::SceneFrame scene_;
  SimFrame frame_;
  std::vector<osi::ReportedDetection> detections_;
  long frames_ = 0;
  double last_time_ = 0;
};

}  // namespace lidarsim::infer
