#pragma once
// What `lidar-infer sim` writes, and the run's statistics.
//
// Per frame NNNN (zero-padded frame index) under the output folder:
//   objects_NNNN.csv   one row per object; column `source` is "reported" (the simulated
//                      detector's list: id = track id, truth_id = ground-truth id or -1 for a
//                      false positive) or "truth" (ground truth in view, id = truth_id);
//                      sensor frame, metres, heading in degrees
//   objects_NNNN.json  {"frame", "time", "reported": [...], "ground_truth": [...]}
//   lanes_NNNN.json    {"frame", "time", "lanes": [{id, type, c0..c3, x_min, x_max}]},
//                      y = c0 + c1 x + c2 x^2 + c3 x^3 in the sensor frame on [x_min, x_max]
//   cloud_NNNN.pcd|ply x y z (sensor frame) intensity class material object_id range
//   pgm_NNNN.png       the PGM channels stacked: range, class, material, intensity, each under a
//                      caption with its colour scale or the classes / materials present
//   bev_NNNN.png       bird's-eye view: ground truth boxes (green), reported (red; coasting
//                      orange), false positives (magenta), lane polynomials (white), points (grey),
//                      with frame and time above and a legend and scale bar on the right
// At the end: summary.json (machine) and summary.md (people).
#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include "common/image.h"
#include "infer/sim_pipeline.h"

namespace lidarsim::infer {

struct SimOutputOptions {
  std::filesystem::path out = "out/sim";
  std::string format = "pcd";  // or "ply"
  bool images = true;          // pgm_*.png and bev_*.png
};

// Writes one frame's files (atomically, each). Returns the milliseconds spent. Throws for a frame
// whose intensity was skipped (SimFrame::intensity_skipped).
double write_frame_outputs(const SimOutputOptions& options, const SimFrame& frame);

// The two pictures of a frame. The map is 800 x 800 px covering [-range, range] m around the
// sensor, below a header band and left of a legend panel; the PGM rows (one image row per beam,
// scaled to about 128 px) each sit below a caption band, all below a header band.
Image bev_image(const SimFrame& frame, double range);
Image pgm_image(const SimFrame& frame);

// Accumulates per-frame statistics and writes the summary.
class SimStats {
 public:
  // `output_ms`: the time the pipeline's thread spent writing this frame's outputs (0 when a
  // writer thread writes them, or the frame is not written).
  void add(const SimFrame& frame, double output_ms = 0);
  // The writer thread's milliseconds per written frame (FrameWriter::frame_ms), after it finished.
  void set_writer_ms(std::vector<double> per_written_frame) { writer_ms_ = std::move(per_written_frame); }

  int frames() const { return static_cast<int>(total_ms_.size()); }
  double mean_ms(int stage) const;
  double p95_ms(int stage) const;
  double mean_total_ms() const;
  double p95_total_ms() const;
  double compute_seconds() const;  // sum over frames of total_ms, seconds
  // scenario seconds simulated / compute seconds (frames / rate over compute time)
  double real_time_factor(double rate_hz) const;

  struct Info {
    std::string scenario, kpi_model, intensity_model, format;
    double rate_hz = 10;
    int threads = 1;
    std::uint64_t seed = 1;
    bool outputs = true;
    bool images = true;
    double wall_seconds = 0;
  };
  // summary.json + summary.md into `out`.
  void write_summary(const std::filesystem::path& out, const Info& info) const;
  std::string to_json(const Info& info) const;
  std::string to_markdown(const Info& info) const;

 private:
  std::array<std::vector<double>, kNumSimStages> stage_ms_;
  std::vector<double> total_ms_, output_ms_;
  std::vector<double> writer_ms_;  // per written frame, on the writer thread
  // Mean and p95 ms per written frame, and where they were spent ("writer thread" or "pipeline thread").
  struct OutputTimes {
    double mean = 0, p95 = 0;
    int frames = 0;
    const char* where = "pipeline thread";
  };
  OutputTimes output_times() const;
  long in_view_ = 0, occluded_ = 0, partly_occluded_ = 0, reported_ = 0, false_positives_ = 0, points_ = 0,
       existing_ = 0, lanes_ = 0;
  int intensity_skipped_ = 0;  // frames run without the UNet (nobody read their intensity)
};

double percentile(std::vector<double> values, double p);  // linear interpolation, p in [0, 1]

}  // namespace lidarsim::infer
