#pragma once
// The simulation pipeline behind `lidar-infer sim`: a scenario run frame by frame through the
// phenomenological sensor model and the point-cloud bridge.
//
//   sample scenario at t -> map -> ego -> sensor -> field of view -> occlusion (visible fraction,
//   lanes behind boxes dropped; static scenery hides what is behind it but is never an object) -> tracking (in the map frame: stable ids, coasting, over-ground
//   velocity) -> KPI manager (errors, misses, false positives) = the reported object list;  visible lanes -> cubic polynomials;
//   PCL generator over the visible boxes, the scenery, the road and lane paint -> PGM -> UNet intensity per
//   cell -> point cloud (sensor frame) with intensity, class, material and object id.
//
// Constructed once; run_frame() reuses every buffer, so after the first frames a run allocates
// (almost) nothing. Each stage is timed with steady_clock; nothing here writes files
// (infer/sim_outputs.h does).
#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "infer/intensity_model.h"
#include "pgm/polar_grid_map.h"
#include "sensor/kpi_manager.h"
#include "sensor/frames.h"
#include "sensor/kpi_model.h"
#include "sensor/occlusion.h"
#include "sensor/pcl_generator.h"
#include "sensor/return_model.h"
#include "sensor/scenario.h"
#include "sensor/scene.h"
#include "sensor/tracking.h"

namespace lidarsim::infer {

// Stages in the order they run; the timing arrays are indexed by these.
enum class SimStage { Sample, Frames, FieldOfView, Occlusion, Tracking, Kpi, Lanes, PclGenerator, Unet, PointCloud };
inline constexpr int kNumSimStages = 10;
const char* to_string(SimStage s);

struct SimOptions {
  std::uint64_t seed = 1;         // KPI manager noise
  sensor::TrackerConfig tracker;  // coasting frames etc.
  sensor::KpiOptions kpi;
  bool intensity = true;          // false: skip the UNet (intensity stays 0)
  bool point_cloud = true;        // false: the object-level model only (no PCL generator, UNet, cloud)
  // With a spread head (lidar-train --heads mean,log_scale_...): intensity drawn from the predicted
  // distribution, per (seed, frame, cell), instead of the mean (infer/intensity_sampling.h).
  bool sample_intensity = false;
  // Terms on the sampled spread (infer/intensity_spread_terms.h); needs sample_intensity.
  std::vector<sensor::RangeNoiseTerm> spread_terms;
  // Another sensor (lidar-infer sim --sensor FILE.json): replaces the scenario's beams, and its
  // vertical field of view and range limits follow the layout's beams and ranges.
  std::optional<pgm::BeamLayout> sensor;
  // Range noise of the PCL generator's returns (sensor/range_noise.h), drawn from `seed`, the
  // frame and the cell; null = exact ranges.
  std::shared_ptr<const sensor::RangeNoiseModel> range_noise;
  // Return model (lidar-infer sim --returns FILE.json): which beams that meet geometry return,
  // drawn from (seed, frame, cell); null = every such beam returns.
  std::shared_ptr<const sensor::ReturnModel> returns;
  // How the intensity UNet's 3x3 kernels are chosen (nn/kernel_plan.h).
  nn::PlanMode kernels = nn::PlanMode::rule;
};

// Puts `layout` in the scenario's sensor (beams, vertical field of view, range limits).
void use_sensor(sensor::Scenario& scenario, const pgm::BeamLayout& layout);

// One reported object with where it came from.
struct ReportedObject {
  sensor::Object object;  // sensor frame; id = track id (false positives: <= -1000)
  int truth_id = -1;      // ground-truth id of the track's last associated object, -1 for a false positive
  bool coasting = false;  // track not measured this frame (a prediction)
};

// The point cloud of one frame (sensor frame), one entry per PGM cell with a return.
struct SimCloud {
  std::vector<float> x, y, z, intensity, cls, material, object_id, range;
  std::vector<int> cell;  // row * cols + col
  std::size_t size() const { return x.size(); }
  void clear();
};

struct SimFrame {
  int index = 0;
  double time = 0;
  sensor::Frame ego;                      // ground truth in the ego frame (all existing objects)
  sensor::Frame sensor;                   // ground truth in the sensor frame after FoV + occlusion
  std::vector<ReportedObject> reported;   // what the simulated detector reports
  std::vector<sensor::LanePolynomial> lanes;
  pgm::PolarGridMap pgm;                  // range, class, material, intensity (predicted), mask, object_id, ...
  SimCloud cloud;
  int objects_existing = 0, objects_in_view = 0, objects_occluded = 0, objects_partly_occluded = 0;
  int returns = 0;
  // True when run_frame was told no one reads this frame's intensity: the UNet did not run, the
  // intensity channel and the cloud's intensity hold 0, so do the network's neighbourhood inputs
  // (incidence, depth_discontinuity: PclGenerator::generate), and write_frame_outputs refuses it.
  bool intensity_skipped = false;
  std::array<double, kNumSimStages> stage_ms{};
  double total_ms = 0;  // all stages (outputs excluded)
};

class SimPipeline {
 public:
  // intensity may be null when options.intensity is false.
  SimPipeline(sensor::Scenario scenario, sensor::KpiModel kpi_model, std::unique_ptr<IntensityModel> intensity,
              SimOptions options = {});
  // Loads the three files; errors name the file (lidarsim::Error).
  static SimPipeline from_files(const std::filesystem::path& scenario, const std::filesystem::path& kpi_model,
                                const std::filesystem::path& intensity_checkpoint, SimOptions options = {});

  const sensor::Scenario& scenario() const { return scenario_; }
  // True when some class's false positives persist over frames (KpiModel fp_persistence).
  bool kpi_model_has_persistence() const;
  int frame_count() const { return scenario_.frame_count(); }
  const IntensityModel* intensity_model() const { return intensity_.get(); }

  // Runs frame k (time k / rate) into `out`, whose buffers are reused between calls. Frames must
  // be run in increasing order (tracking and the KPI noise carry state from frame to frame).
  // intensity = false skips the UNet for this frame (out.intensity_skipped) and the input channels
  // only it reads: its prediction is read only by the outputs (PGM image, point cloud file),
  // carries no state to later frames and changes nothing else, so a caller that writes only every
  // N-th frame's outputs (lidar-infer sim --every N) need not pay for it on the others.
  void run_frame(int k, SimFrame& out, bool intensity = true);
  // The same stages on ground truth given from outside (the OSI interface, infer/osi_runner.h):
  // `map_frame` as sample_frame() would give it (map frame: time, ego pose, objects, lanes).
  // Same ordering rule as run_frame.
  void run_ground_truth(int k, const sensor::Frame& map_frame, SimFrame& out);

 private:
  void run_stages(int k, const sensor::Frame& map_frame, std::chrono::steady_clock::time_point start, SimFrame& out,
                  bool intensity = true);
  // The stages of run_stages, in order.
  void occlude(SimFrame& out);
  void track(const SimFrame& out, const sensor::Pose& map_from_sensor);
  void report(SimFrame& out, const sensor::Pose& map_from_sensor);
  void generate_returns(int k, SimFrame& out, bool predict);
  void predict_intensity(int k, SimFrame& out);
  void fill_cloud(SimFrame& out);

  sensor::Scenario scenario_;
  std::unique_ptr<IntensityModel> intensity_;
  SimOptions options_;
  sensor::Tracker tracker_;
  sensor::KpiManager kpi_;
  // The sensor's pose in the map at the last frame: the KPI manager's persistent false positives
  // (ghost tracks) are held still in the world by the sensor's motion since then.
  std::optional<sensor::Pose> last_map_from_sensor_;
  sensor::Occlusion occlusion_;
  sensor::PclGenerator pcl_;
  std::vector<std::string> extra_channels_;
  // scratch
  sensor::SampleCursor cursor_;  // keyframe intervals of the last frame (frames run in order)
  sensor::Frame map_frame_;
  std::vector<sensor::Object> detections_, tracked_map_, tracked_, kpi_out_, pcl_objects_;
  std::vector<sensor::HeadingTrig> heading_trig_;  // cos / sin of each sensor-frame object's heading, from the FoV stage
  std::vector<float> predicted_;
  std::vector<double> column_cos_, column_sin_;  // point cloud: direction of each PGM column
};

// A checkpoint with untrained (He-initialised) UNet weights and the default encoder and the given
// beam layout in /config, as lidar-train writes them: for tests and benchmarks when no trained
// model is at hand. Never ship such a file as a model.
void write_untrained_checkpoint(const std::filesystem::path& path, int base, int depth, std::uint64_t seed,
                                const pgm::BeamLayout& layout);

}  // namespace lidarsim::infer
