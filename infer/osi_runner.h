#pragma once
// The sensor model behind the OSI interface: osi3.SensorView in, osi3.SensorData out, one frame
// at a time, through the same pipeline as `lidar-infer sim` (frames, field of view, occlusion,
// tracking, KPI manager, lanes, PCL generator, PGM, UNet intensity). Shared by `lidar-infer osi`
// and the OSMP FMU (infer/fmu).
//
// The sensor's beams, field of view and range come from a scenario file's "sensor" block (the
// bundled demo's by default); its mount is replaced by the SensorView's mounting_position. The
// pipeline is built on the first SensorView, so the mount must not change during a run.
//
// Several detectors (lidar_sensor_view entries, osi::Detector): the objects and lanes are the
// virtual sensor's (SensorView.mounting_position), and each detector gets its own point cloud in
// its own frame as feature_data.lidar_sensor[i] with its sensor_id. Detectors at the virtual mount
// share the main pipeline's cloud; one at another mount runs a pipeline of its own (same sensor,
// KPI model and seed; its objects are not reported), whose intensity model comes from the
// runner's loader. The detectors and their mounts must not change during a run either.
#include <functional>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "infer/intensity_model.h"
#include "infer/sim_pipeline.h"
#include "osi/messages.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"

namespace osi3 {
class SensorView;
}  // namespace osi3

namespace lidarsim::infer {

// `--ideal`: a model perfect by request. The KPI manager's errors, misses, false positives and
// heading flips off, and a track is confirmed on its first detection, so frame 0 already reports
// every visible object (its velocity and acceleration the ground truth's: a new track starts from
// the detection). Tracking and occlusion stay.
void make_ideal(SimOptions& options);

class OsiRunner {
 public:
  // Another intensity model, for a detector at a mount of its own; empty: such detectors are an error.
  using IntensityLoader = std::function<std::unique_ptr<IntensityModel>()>;

  // intensity may be null when options.intensity is false.
  OsiRunner(sensor::SensorSpec sensor, sensor::KpiModel kpi, std::unique_ptr<IntensityModel> intensity,
            SimOptions options = {}, IntensityLoader loader = {});
  // The sensor block of `scenario`, the KPI model and the intensity checkpoint (HDF5 or weights
  // file, IntensityModel::load); errors name the file. Inline, so that only its callers link the
  // HDF5 reader: the FMU's model library builds its runner with IntensityModel::load_weights.
  static OsiRunner from_files(const std::filesystem::path& scenario, const std::filesystem::path& kpi_model,
                              const std::filesystem::path& intensity_checkpoint, SimOptions options = {}) {
    sensor::Scenario s = sensor::read_scenario(scenario);
    sensor::KpiModel k = sensor::load_kpi_model(kpi_model);
    std::unique_ptr<IntensityModel> m;
    IntensityLoader loader = [intensity_checkpoint] {
      return std::make_unique<IntensityModel>(IntensityModel::load(intensity_checkpoint));
    };
    if (options.intensity && options.point_cloud) m = loader();
    return OsiRunner(s.sensor, std::move(k), std::move(m), options, std::move(loader));
  }

  // One frame (the SensorView decoded by osi::decode_sensor_view), the SensorData as wire bytes
  // (osi::encode_sensor_data: the same bytes as SerializeToString of the message build_sensor_data
  // fills, without building it) from out[prefix] on. Bad input throws lidarsim::Error
  // "<source>: message <index>: <field>: <what>" (see osi::scene_from_sensor_view; also a mount
  // that changes or a timestamp that does not advance).
  void step(const osi::msg::SensorView& in, long index, const std::string& source, std::string& out,
            std::size_t prefix = 0);

  // With libprotobuf (infer/osi_runner_proto.cpp; not in the FMU): the SensorData as a message,
  // and both from an osi3.SensorView message (its bytes decoded as above).
  void step(const osi::msg::SensorView& in, long index, const std::string& source, osi3::SensorData& out);
  void step(const osi3::SensorView& in, long index, const std::string& source, osi3::SensorData& out);
  void step(const osi3::SensorView& in, long index, const std::string& source, std::string& out,
            std::size_t prefix = 0);
  // The last step's SensorData built again as a message (the benchmark times both writers on one
  // frame); throws before the first step.
  void last_sensor_data(osi3::SensorData& out) const;

  // Where the last step's time went (wall clock): the SensorView into our scene, the model's
  // stages (every pipeline: SimFrame::total_ms and the detectors' own), the SensorData out.
  struct StepTimes {
    double scene_ms = 0, model_ms = 0, output_ms = 0;
  };
  const StepTimes& last_times() const { return times_; }
  // What the last step reported: objects, and lidar detections over all detectors.
  std::size_t reported_objects() const { return detections_.size(); }
  std::size_t reported_points() const;

  const SimFrame& last_frame() const { return frame_; }
  long frames() const { return frames_; }
  const sensor::SensorSpec& sensor() const { return sensor_; }
  const IntensityModel* intensity_model() const { return intensity_ ? intensity_.get() : nullptr; }

 private:
  sensor::SensorSpec sensor_;
  std::optional<sensor::KpiModel> kpi_;               // moved into the pipeline on the first frame
  std::unique_ptr<IntensityModel> intensity_;         // idem
  SimOptions options_;
  IntensityLoader loader_;
  sensor::KpiModel kpi_spare_;                        // for the pipelines of detectors at other mounts
  std::optional<SimPipeline> pipeline_;
  // A detector at a mount other than the virtual sensor's, with its own pipeline.
  struct OwnMount {
    SimPipeline pipeline;
    SimFrame frame;
  };
  std::vector<std::unique_ptr<OwnMount>> own_;
  std::vector<int> cloud_of_;                 // per detector: -1 the main pipeline's cloud, else index in own_
  std::vector<sensor::Pose> detector_mounts_;  // the first message's
  std::vector<osi::CloudRef> clouds_;
  void build(const std::string& source, long index);
  void advance(const osi::msg::SensorView& in, long index, const std::string& source);  // all but the output
  StepTimes times_;
  osi::IdMap ids_;
  osi::SceneFrame scene_;
  SimFrame frame_;
  std::vector<osi::ReportedDetection> detections_;
  long frames_ = 0;
  double last_time_ = 0;
};

}  // namespace lidarsim::infer
