#pragma once
// The object loop's false-positive analysis (internal to qualify/). The KPI manager draws
// a class's false positives as a Poisson count per frame, each placed by independent quantiles of
// range, azimuth and score (sensor/kpi_model.h). The measured false positives (the calibration's
// association, objects.h FalsePositiveRecord) are compared with that, per held-out frame, as counts:
//   outcome   per frame, class and cell of a grid over (range, azimuth, score) — equal-count bins of
//             the fit split's false positives (5 x 5 x 4) — the number of false positives;
//   model     Poisson with the model's expected count in the cell, a mixture of components (a rate
//             per frame x the product of its range, azimuth and score cell probabilities, from the
//             quantiles by linear interpolation as the manager samples them);
//   loss      the held-out Poisson deviance of each block's counts per class and cell (expected: the
//             model's per-frame counts summed over the block's frames); score = 1 - D_after / D_before,
//             pooled over both folds. Blocks, not frames: the candidates are rates, and which frames of
//             a block carry its false detections (a persistent ghost over 30 frames) is nothing a rate
//             can say, so per frame the deviance would be mostly that unexplainable part;
//   blocks    100-frame chunks of a sequence, also what the bootstrap resamples (frames and the false
//             detections that persist over them stay together; a fold holds out whole sequences).
// Candidates, per feature (kFpFeatures) and form, fitted on a fold's fit sequences only:
//   fp_rate_table   per class, per bin of the feature (10 equal-count bins): a rate and the bin's
//                   quantiles of range, azimuth and score;
//   fp_rate_window  the same with the bins below, inside and above one window of the feature (a step
//                   when it reaches an end), edges chosen on the fit split among 20 equal-count bins.
// A bin's placement: its own false positives of the class pooled with 20 pseudo ones from a reference
// (the class's over all bins; for the binned attribute the bin's of every class), so a bin of a few
// false positives does not put nothing where the held-out ones land.
// Each form is a candidate for every class at once (one window for all, judged on all classes'
// false positives) and for each class alone (its own window chosen on its own fit deviance, the other
// classes keep the base; judged on that class's held-out false positives): an effect in one class
// (a cell of pedestrian ghosts) is a share of that class's deviance, a sliver of all classes', and
// the other classes' tables only add their fitting noise to the judgement.
// The base model (one component per class) cannot hold a joint effect such as a hot spot (false
// detections in a window of azimuth at one range) or a score that falls with range; these forms can.
// Frame features (truth_count, frame_index) keep the class's placement and give each frame bin its own
// rate; they are tested and reported, but the KPI model's fp_table is over a false positive's own
// attribute, so only range, azimuth and score can be added.
#include <algorithm>
#include <array>
#include <filesystem>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "qualify/objects/object_folds.h"

namespace lidarsim::qualify::obj {

inline const std::vector<std::string> kFpFeatures = {"range", "azimuth", "score", "truth_count", "frame_index"};
inline constexpr int kFpAttributeFeatures = 3;  // the first three: attributes of the false detection
inline constexpr int kFpBlockFrames = 100;      // bootstrap block: consecutive frames of one sequence
inline constexpr long kFpWindowSide = 30;       // fit false positives inside a window, at least
inline constexpr int kFpQuantiles = 21;         // placement quantiles, as lidar-calibrate stores them

// The bin of x among sorted cut points: 0 below the first, cuts.size() from the last on.
inline int fp_cut_bin(const std::vector<double>& cuts, double x) {
  return static_cast<int>(std::upper_bound(cuts.begin(), cuts.end(), x) - cuts.begin());
}

// The cells the rate is judged on: cut points of range, azimuth and score.
struct FpGrid {
  std::vector<double> range, azimuth, score;
  int cells() const;
  int cell(double r, double a, double s) const;
};
FpGrid fp_grid(const ObjectSet& fit);

// A set's frames and false positives, by grid cell.
struct FpData {
  struct Frame {
    int block = 0;
    std::array<double, 2> feature{0, 0};  // truth_count, frame_index
    std::vector<std::array<int, 3>> counts;  // (class, cell, count) of its false positives
  };
  std::vector<Frame> frames;
  std::vector<FalsePositiveRecord> fps;  // the set's, with slot = index in frames
};
FpData fp_data(const ObjectSet& set, const FpGrid& g);

struct FpComponent {
  double rate = 0;                // per frame
  std::vector<double> rq, aq, sq;  // quantiles of range, azimuth, score
};

// One false-positive model of the three classes. Attribute features: every component every frame (a
// mixture); frame features: the frame's bin's component. feature -1: the base model's own.
struct FpModel {
  int feature = -1;
  int cls = -1;  // the class the candidate models (its table); -1: every class. Other classes: the base's
  std::vector<double> cuts;  // bin k = [cuts[k-1], cuts[k])
  PerClass<std::vector<FpComponent>> comps;  // per class, per bin
  PerClass<std::vector<std::vector<double>>> mu;  // compiled: per class, bin, cell: expected count
  // fp_rate_cell (object_fp_cell.h): the rectangle range [cell[0], cell[1]) x azimuth [cell[2], cell[3])
  // and the cell's rate per frame summed over classes; cell_rate < 0: not a cell.
  std::array<double, 4> cell{0, 0, 0, 0};
  double cell_rate = -1;
  void compile(const FpGrid& g, const PerClass<double>& floor);
  int frame_bin(const FpData::Frame& f) const;
};

FpModel fp_base(const sensor::KpiModel& base);
// The base of the fold's judgement: the base model's own, and for a class the base model leaves out
// (kpi_fit drops a class with too few matched detections, min_samples) what lidar-calibrate would
// have fitted from the class's false positives on `fit` (rate and quantiles). False positives need
// no truth: a class absent from the truth of one fold's fit sequences (KITTI sequences without a
// pedestrian) still has them, and without this every model would leave them at the floor, an
// equal and huge deviance before and after that drowned any effect in that class.
FpModel fp_base(const sensor::KpiModel& base, const FpData& fit);
// The candidate of `feature` (index in kFpFeatures), table or window, fitted on `fit`; for class
// `cls` only (the window chosen on that class's deviance, the other classes keep the base), or for
// every class (-1, one window for all).
FpModel fit_fp_model(const FpData& fit, const sensor::KpiModel& base, int feature, bool window, int bins,
                     const FpGrid& g, const PerClass<double>& floor, int cls = -1);
// Poisson deviance of `m` on the frames of `d` (per frame, summed over classes and cells).
std::vector<double> fp_deviance(const FpModel& m, const FpData& d);
// The floor added to every cell's expected count (the same for every model of a fold): 0.1 % of the
// class's fit rate spread over the cells, so an empty cell costs a finite deviance.
PerClass<double> fp_floor(const FpData& fit, int cells);

// The model with each class's fp_table from an attribute candidate.
sensor::KpiModel with_fp_table(const sensor::KpiModel& m, const FpModel& fp);

struct FpCandidate {
  int feature = 0;
  bool window = false;
  bool cell = false;  // fp_rate_cell (object_fp_cell.h): feature is range, the table's, with a rectangle in azimuth
  int cls = -1;  // -1: a table for every class, judged on all classes; else that class's, judged on it
  std::string form;  // fold 1's
  double effect_size = 0;  // fold 1: largest ratio of the candidate's to the base's expected count in a cell
  double score = 0;
  std::array<double, 2> interval{0, 0};  // of the score
  std::array<double, 2> change{0, 0};    // of the held-out deviance per frame, after - before
  double deviance_before = 0, deviance_after = 0;  // per held-out frame
  double error_before = 0, error_after = 0;        // false-positive rate error (fp_rate_error)
  long frames = 0, fps = 0;
  std::string decision;
};

// Persistence of false positives (ghost tracks; object_fp_persistence.cpp). A rate table cannot say
// which frames carry a block's false detections; KITTI's persist (a ghost of a pole over 30 frames).
// Statistics of a set's false positives, per class:
//   persistence share  false positives with one of the same class within kFpPersistGate (BEV) in the
//                      previous frame of the sequence (the outcome judged);
//   track lengths      the false positives linked greedily one to one (nearest first) to the previous
//                      frame's within the gate: tracks of length 1, 2, 3-5, 6-10, 11-30, > 30 frames;
//   dispersion         variance / mean of the count per frame.
// The candidate (fp_persistence in the KPI model), per class fitted on the fit sequences: a share of
// ghosts and their survival (the rest last one frame; the rate holds). Survival: the continuation of
// runs, sum max(0, L - 2) / sum (L - 1) over the tracks (a geometric run continues with the survival
// at every length, a one-frame false positive adds to neither); ghost share: bisection so that the KPI
// manager's false positives, drawn on the fit split's frames, have the fit split's persistence share
// (when even all ghosts fall short, share 1 and the survival by bisection instead); the target is then
// scaled by the ratio of the share the re-simulated fit sequences get to the false positives' own
// (the re-simulation adds non-persistent false positives: truth detections placed beyond the gate) and
// solved again. A jitter (robust sd
// of a linked pair's lateral step) and a score AR(1) (Spearman of linked pairs' scores, as a Gaussian
// copula's correlation). Judged on the held-out sequences: the KPI manager re-simulates
// them (4 seeds) with the fold's base model and with the base plus persistence; error = RMS over
// classes (>= 20 measured held-out false positives) of simulated minus measured persistence share;
// score = 1 - error_after / error_before; intervals by a basic bootstrap over the held-out 100-frame
// blocks (measured and simulated resampled together). Added when score >= threshold and the 95 %
// interval of error_after - error_before lies below 0 (rule fixed before KITTI's numbers were seen).
inline constexpr double kFpPersistGate = 1.5;  // m
inline constexpr int kFpTrackBins = 6;

// Per class: false positives, those with a predecessor, frames, sum of counts, sum of squared counts.
using FpPersistSums = PerClass<std::array<double, 5>>;
struct FpPersistStats {
  std::map<int, FpPersistSums> blocks;                     // block id (FpData's) -> sums
  PerClass<std::array<double, kFpTrackBins>> tracks{};  // per class: tracks by length bin
  PerClass<std::vector<double>> lateral_step;          // linked pairs: step of y (sensor frame), m
  PerClass<std::vector<std::array<double, 2>>> score_pairs;  // linked pairs: (score, previous score)
  PerClass<double> links{}, links2{};  // per class over tracks of length L: sum (L - 1), sum max(0, L - 2)
};
FpPersistStats fp_persist_stats(const ObjectSet& set);

struct FpPersistClass {
  double survival = 0, ghost_share = 1, jitter = 0, score_ar1 = 0;  // fitted on fold 1's fit sequences
  long held_fps = 0;
  double share_measured = 0, share_before = 0, share_after = 0;
  double dispersion_measured = 0, dispersion_before = 0, dispersion_after = 0;
  std::array<double, kFpTrackBins> tracks_measured{}, tracks_before{}, tracks_after{};  // shares of tracks
  double mean_track_measured = 0, mean_track_before = 0, mean_track_after = 0;           // frames
};

struct FpPersistence {
  PerClass<FpPersistClass> classes;
  std::array<PerClass<double>, 2> survival{};  // per fold, class
  double effect_size = 0;  // fold 1: share of the simulated false positives that are survivors
  double error_before = 0, error_after = 0, score = 0;
  std::array<double, 2> interval{0, 0}, change{0, 0};
  bool added = false;
  std::string decision;
};

// The persistence candidate judged on the two folds (the fold's base models, its fit sequences only).
FpPersistence analyse_fp_persistence(const TrackingData& data, const std::array<Fold, 2>& folds, double threshold,
                                     std::uint64_t seed);
// Each class's fp_persistence fitted on the sequences `fit_idx` (their records `fit`; the model's own
// rates and placement drawn).
sensor::KpiModel with_fp_persistence(const sensor::KpiModel& m, const TrackingData& data, const std::vector<int>& fit_idx,
                                     const ObjectSet& fit, std::uint64_t seed);

struct FpAnalysis {
  std::vector<FpCandidate> candidates;
  FpPersistence persistence;
  int added = -1;  // index of the added candidate
  double simulated_before = -1, simulated_after = -1;  // rate error re-simulated by the KPI manager
  int frames = 0, fps = 0;
};

// RMS over classes and cells of the held-out false positives per frame minus the model's expected count,
// beyond the measured rate's Poisson noise: per cell (measured, model, noise variance), the variance
// subtracted from the mean square (an unbiased estimate of the squared error the model makes).
double fp_rate_error(const std::array<std::vector<std::array<double, 3>>, 2>& per_fold);

// Every candidate judged on the two folds; the best attribute candidate is added when its score is at
// least `threshold` and the block-bootstrap 95 % interval of the change of the held-out deviance lies
// below 0. The added one is re-simulated with the KPI manager on each fold's held-out sequences.
FpAnalysis analyse_false_positives(const TrackingData& data, const std::array<Fold, 2>& folds, double threshold,
                                   int bins, std::uint64_t seed);
// The added candidate refitted on every sequence (`whole`'s fit split) and written into `m`.
sensor::KpiModel with_fitted_fp_table(const sensor::KpiModel& m, const Fold& whole, const FpCandidate& c, int bins);

nlohmann::json fp_json(const FpAnalysis& a, double threshold);
std::string fp_markdown(const nlohmann::json& fp);
// The persistence candidate's held-out track lengths as a PNG: per class, the share of false-positive
// tracks lasting at least L frames, measured (bars) against the model before and after (marks).
// `persistence` is fp_json's "persistence"; returns the picture's caption.
std::string write_fp_tracks_png(const std::filesystem::path& path, const nlohmann::json& persistence);

}  // namespace lidarsim::qualify::obj
