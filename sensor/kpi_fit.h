#pragma once
// Calibration of the KPI model from measured data: ground truth vs real detections, frame by
// frame along tracks. Generic over the source (data/kitti_tracking.h turns KITTI tracking +
// AB3DMOT detections into CalibrationSequence). Also measures the same statistics on any
// sequence, so a model can be re-simulated on the same ground truth and compared.
#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "sensor/kpi_model.h"
#include "sensor/scene.h"

namespace lidarsim::sensor {

struct CalibrationFrame {
  std::vector<Object> truth;       // classes to fit; id = track id (stable in the sequence);
                                   // visible_fraction set (for KITTI from the occlusion level)
  std::vector<int> occlusion;      // per truth: KITTI occlusion level 0..3 (reporting only)
  std::vector<Object> others;      // other ground truth (Van, Person_sitting, ...): detections
                                   // within the gate of one are neither matches nor false positives
  std::vector<Object> detections;  // with score
};

struct CalibrationSequence {
  std::string name;
  double frame_dt = 0.1;  // s
  std::vector<CalibrationFrame> frames;  // consecutive frames
};

// A detection cell's (range x visibility) rate is shrunk toward its range row's, the row's toward
// the class's, as by a Beta prior worth this many objects: a cell weighs as much as its row at 15
// objects, the count below which the raw rate was not used at all before.
inline constexpr double kDetectionPriorObjects = 15;

struct FitOptions {
  std::vector<std::string> classes{kModelledClasses.begin(), kModelledClasses.end()};
  double gate = 2.0;       // m, bird's-eye-view centre distance for a match
  double min_score = 0.0;  // detections with score <= min_score are ignored
  std::vector<double> range_bin_edges = {0, 10, 20, 30, 40, 50, 60, 70};
  std::vector<double> visibility_bin_edges = {0, 0.4, 0.8};
  int min_samples = 20;    // fewer samples in a bin: use the pooled value
  int quantiles = 21;      // score / false-positive quantiles stored
};

// Per frame: for each truth object the index of its matched detection or -1. Same class only,
// score > min_score, BEV distance <= gate, minimum total distance (Hungarian).
std::vector<int> match_truth_to_detections(const std::vector<Object>& truth, const std::vector<Object>& detections,
                                           double gate, double min_score);

// Measured statistics (what the report compares between real and simulated detections).
struct ErrorStats {
  long n = 0;
  double mean = 0, std = 0, lag1 = 0, excess_kurtosis = 0;
};
struct ClassStats {
  std::vector<long> truth_by_range, detected_by_range;  // per range bin
  std::array<long, 4> truth_by_occlusion{}, detected_by_occlusion{};
  long truth = 0, detected = 0, truth_beyond_50 = 0, detected_beyond_50 = 0;
  double miss_burst_mean = 0;          // mean length of runs of consecutive misses along tracks
  double misses_in_bursts = 0;         // fraction of missed frames in runs of length >= 2
  long false_positives = 0;
  double flip_rate = 0;
  double score_mean = 0;
  std::array<ErrorStats, kNumKpiParams> errors;
  std::array<std::vector<double>, kNumKpiParams> samples;  // the matched errors themselves
  double recall() const { return truth ? double(detected) / truth : 0; }
  double recall_beyond_50() const { return truth_beyond_50 ? double(detected_beyond_50) / truth_beyond_50 : 0; }
};
struct CalibrationStats {
  std::vector<double> range_bin_edges;
  long frames = 0;
  std::map<std::string, ClassStats> classes;
};

CalibrationStats measure_calibration_stats(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt);

KpiModel fit_kpi_model(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt);

// One parameter's error on one matched detection, for fitting that parameter's noise alone: the
// object loop refits a class's noise once a conditional term has taken its share of the error.
struct ErrorSample {
  int seq = 0, track = 0, frame = 0, range_bin = 0, visibility_bin = 0;
  double value = 0;
};
// The error model fit_kpi_model fits for one parameter of one class (range-bin means and sigmas,
// visibility scale, per-track constant when asked, AR(1) and innovation mixture), from samples
// in any order. Bins outside opt's edges are an error.
ErrorModel fit_error_model(std::vector<ErrorSample> samples, const FitOptions& opt, bool per_track_constant);

// The baseline DESIGN.md warns about: every error Gaussian and iid (one bin, no correlation,
// no heavy tails, no per-track sizes), misses independent, no flips; same pooled mean and std.
KpiModel gaussian_iid_model(const std::vector<CalibrationSequence>& seqs, const FitOptions& opt);

// Histogram intersection in [0, 1] of two samples over `bins` equal bins spanning the 1st-99th
// percentile of `reference`, plus one overflow bin at each end.
double histogram_intersection(const std::vector<double>& reference, const std::vector<double>& other, int bins = 40);

// The truth's velocity and acceleration by differences of each track's box centre over consecutive
// frames, as the object loop's features (qualify/objects/objects.h): central where the track has both
// neighbours (acceleration (p[f+1] - 2 p[f] + p[f-1]) / dt^2, 3-D), one-sided velocity and zero
// acceleration at a track's ends, zero for a single frame. Relative to the moving sensor. Any
// motion the truth carried is replaced.
std::vector<CalibrationSequence> with_truth_motion(std::vector<CalibrationSequence> seqs);

// The same ground truth with detections replaced by the KPI manager's output (fixed seed). The
// manager sees the truth with_truth_motion (the calibration truth of KITTI carries none), so that
// conditional terms on speed, velocity or acceleration see what the loop that fitted them saw.
std::vector<CalibrationSequence> resimulate(const std::vector<CalibrationSequence>& seqs, const KpiModel& model,
                                            std::uint64_t seed);

// Markdown table: measured vs simulated detection rate by range bin and the other statistics.
std::string format_comparison(const CalibrationStats& measured, const CalibrationStats& simulated);

}  // namespace lidarsim::sensor
