#pragma once
// Object-level qualification (KPI model vs measured detections) and the object loop.
//
// Input: a KITTI tracking folder as it comes (label_02/, calib/, detection/<det>_<Class>_val/,
// optionally evaluate_tracking.seqmap.val). Per ground-truth object and frame an ObjectRecord:
// the matched detection's errors (sensor/kpi_fit.h matching: same class, score > 0, 2 m BEV
// gate, Hungarian) and the candidate features of the loop's vocabulary.
//
// Feature vocabulary (all from ground truth, sensor frame; velocities by central differences
// of the track's box centre, i.e. relative to the moving sensor):
//   range                    BEV distance of the box centre, m
//   azimuth                  atan2(y, x), rad
//   radial_velocity          velocity along the line of sight, m/s (> 0 receding)
//   speed                    |velocity|, m/s
//   longitudinal_velocity    velocity along the box heading, m/s
//   lateral_velocity         velocity across the box heading, m/s
//   acceleration             |change of velocity| / dt, m/s^2: BEV norm of the central second difference
//                            (p[f+1] - 2 p[f] + p[f-1]) / dt^2; 0 at a track's ends
//   heading_to_line_of_sight |heading - azimuth| folded to [0, pi/2] (0: seen end-on), rad
//   occlusion                KITTI occlusion level 0..3
//   truncation               the label's truncated clamped to [0, 1] (sensor::Object::truncation; KITTI
//                            tracking labels give a level 0, 1, 2, so 0 or 1 there)
//   class                    0 Car, 1 Pedestrian, 2 Cyclist
//   size                     box length, m
//   box_width, box_height    box width and height, m (width errors follow the true width)
//   track_age                frames since the track's first appearance
// The KPI model (sensor/kpi_model.h) already conditions on class everywhere and on the visibility
// bin (occlusion level) in detection and in the errors' spread, not in their mean; the loop ranks
// every other feature x target x form (object_candidates.h used_by_model), range too: the model's
// fixed range bins hold none of what lies between their edges, and candidates are fitted net of them. Every
// feature but occlusion and class is one the KPI manager computes (sensor::conditional_feature),
// so the top one can enter the model as a conditional term.
#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/kitti_tracking.h"
#include "qualify/residual.h"
#include "sensor/kpi_fit.h"
#include "sensor/kpi_model.h"

namespace lidarsim::qualify {

inline const std::vector<std::string> kObjectFeatures = {
    "range",      "azimuth",    "radial_velocity", "speed", "longitudinal_velocity", "lateral_velocity",
    "acceleration", "heading_to_line_of_sight", "occlusion", "truncation", "class", "size", "box_width", "box_height",
    "track_age"};
// Residual targets: errors of the matched detection, and detection itself (1 detected, 0 missed).
inline const std::vector<std::string> kObjectTargets = {"position_along", "position_across", "length",
                                                        "width",          "height",          "heading",
                                                        "detection"};
// The object loop's classes are the KPI model's: record and table index c is kObjectClasses[c].
inline constexpr int kObjectClassCount = sensor::kModelledClassCount;
inline const auto& kObjectClasses = sensor::kModelledClasses;
// One value per modelled class, indexed like kObjectClasses.
template <class T>
using PerClass = std::array<T, kObjectClassCount>;
inline constexpr int kObjectTargetCount = 7;
inline constexpr int kDetectionTarget = 6;

struct ObjectRecord {
  int seq = 0, frame = 0, track = 0, cls = 0;
  int range_bin = 0, visibility_bin = 0;
  bool detected = false;
  std::array<double, kObjectTargetCount> value{};  // errors (NaN when missed), then detected 0/1
  std::vector<double> feature;                     // kObjectFeatures order
};

// A false positive: a detection of a modelled class with score > min_score that sensor/kpi_fit.h's
// association matched to no truth and that is not within the gate of other ground truth (Van, ...),
// exactly what lidar-calibrate counts into false_positive_rate.
struct FalsePositiveRecord {
  int slot = 0;  // the frame's index in ObjectSet::frame_seq
  int cls = 0;   // 0 Car, 1 Pedestrian, 2 Cyclist
  double range = 0, azimuth = 0, score = 0;  // BEV range (m), atan2(y, x) (rad), detector score
};

struct ObjectSet {
  std::vector<ObjectRecord> records;
  std::vector<PerClass<int>> false_positives;  // per frame, per class
  std::vector<int> frame_seq;                       // sequence index of each frame
  std::vector<int> frame_index;                     // the frame's index in its sequence
  std::vector<int> frame_truths;                    // ground-truth objects of the three classes in the frame
  std::vector<FalsePositiveRecord> fp_records;      // every false positive, frame by frame
};

struct TrackingData {
  std::vector<std::string> names;
  std::vector<data::KittiTrackingSequence> kitti;
  std::vector<sensor::CalibrationSequence> calib;
};

// Reads the sequences of `seqmap` (default DIR/evaluate_tracking.seqmap.val; without one, every
// label_02/*.txt) that DIR holds. Errors (lidarsim::Error naming the file): DIR or label_02/ or
// calib/ missing, a listed sequence's calib file missing, no detection folder for `detector`,
// fewer than `min_sequences` sequences present.
TrackingData load_tracking(const std::filesystem::path& dir, const std::string& seqmap, const std::string& detector,
                           int min_sequences = 1);

// Records of the given sequences; `detections` overrides the measured detections (one
// CalibrationSequence per sequence, e.g. sensor::resimulate), else calib's own are used.
ObjectSet collect_objects(const TrackingData& data, const std::vector<int>& sequences,
                          const std::vector<sensor::CalibrationSequence>* detections = nullptr,
                          const sensor::FitOptions& opt = {});

// How the loop's fitted bias terms are shrunk by their own track-bootstrap uncertainty on the fit
// sequences (qualify/objects/object_terms.h shrink_by_track_bootstrap), so that a bin that a few tracks
// carry cannot enter the model at full size: not at all, every table's bins towards 0, or the
// pooled table towards 0 and each class's own table towards the pooled one.
enum class TermShrink { Off, TowardsZero, TowardsPooled };

// `lidar-qualify objects`: the model re-simulated on the ground truth vs the measured
// detections; writes report.json, report.md and PNGs into out_dir. Returns the JSON.
// With `nested`, the held-out table gets a second model column free of the loop's leak: for each
// outer fold the loop (loop_objects, its own inner even/odd split) runs on that fold's fit
// sequences only, and the model it writes is scored on the outer held-out sequences (the loop's
// models and reports are written to out_dir/nested_fold_K_*).
// shrink_terms, pool_track_spread: the recipe refitted on each half (and the nested loop) as LoopOptions's.
// held_out_seeds: simulation seeds per fold and model in the held-out table. A model with per-track
// constant errors draws one offset per track and seed, so its simulated histogram carries the
// Monte Carlo noise of seeds x tracks draws, and noise lowers an intersection; the iid model's
// samples are all independent. The seeds must make that noise small beside the held-out tracks'
// own uncertainty for the smallest class (Cyclist, ~23 held-out tracks on KITTI), or the table
// favours the iid model by noise alone: 256 does (32 cost Cyclist length 0.03). Tests pass fewer.
inline constexpr int kHeldOutSeeds = 256;
nlohmann::json qualify_objects(const TrackingData& data, const sensor::KpiModel& model,
                               const std::filesystem::path& out_dir, std::uint64_t seed = 1, bool nested = false,
                               TermShrink shrink_terms = TermShrink::Off, bool pool_track_spread = false,
                               int held_out_seeds = kHeldOutSeeds);

struct LoopOptions {
  double threshold = 0.05;  // held-out share of residual variance below which nothing stands out
  int bins = 10;
  std::filesystem::path plots_dir;  // where to write residual-vs-feature PNGs (empty: none)
  std::filesystem::path out_model;  // where to write the refitted KPI model (empty: not written)
  std::uint64_t seed = 1;           // KPI manager seed of the re-simulation
  int max_effects = 0;              // bias forms added per run, at most one per target (0: no limit)
  // Bias terms shrunk towards 0 by their track-bootstrap uncertainty on the fit sequences
  // (qualify/objects/object_terms.h shrink_by_track_bootstrap; TermShrink above).
  TermShrink shrink_terms = TermShrink::Off;
  // The base model's per-track size constants partially pooled across classes (object_folds.h
  // pool_track_spread), so a class with few tracks borrows the others' ratio of track to frame spread.
  bool pool_track_spread = false;
  // Seeds of the re-simulated distribution check that keeps a term per class
  // (object_distribution.h); fewer is faster and biased against per-track terms.
  int distribution_seeds = kHeldOutSeeds;
  // A candidate is added only when its score's bound simultaneous over the candidates it was picked
  // from lies above 0 (qualify/objects/object_selection.h): the best of ~200 candidates clears its own 95 %
  // interval by chance far more often than 1 run in 40. Off: its own interval alone decides.
  bool selection_bound = true;
};

// `lidar-qualify loop objects`, a two-fold cross-fit: fold 1 fits the base model on the
// even-indexed sequences and judges the odd-indexed ones, fold 2 the other way round, so every
// sequence is held out once. With at most 3 sequences, the features fixed to the sensor
// (object_folds.h kSensorFixedFeatures: azimuth, range) are judged on a second cross-fit of the same
// shape whose folds are blocks of time within each sequence, tracks kept whole
// (object_folds.h split_into_time_blocks); a candidate the held-out data cannot judge (one
// sequence per fold for a feature that can depend on the place, or fewer than 10 held-out tracks
// in a fold) is reported as "the data cannot decide: <why>" instead of ruled out or rejected. Residuals (measured error - model's conditional mean; detected -
// detection probability) on each fold's held-out sequences; features ranked by the pooled
// held-out R^2 of a per-class binned-mean table fitted on the fold's fit sequences (best target per
// feature; 95% interval by a block bootstrap over held-out tracks). The top one is added as a
// per-class per-bin bias table on that target (the conditional term) if its score clears the
// threshold and the refit lowers the held-out RMS of the winsorised residuals beyond the
// track-to-track noise (block-bootstrap interval of the change below 0); else it is reported as
// rejected. "before"/"after": the raw held-out RMS residual of that target over both folds.
// The term also goes into a refitted KPI model (base + the loop's range-bin offsets +
// sensor::ConditionalTerm, fitted on every sequence; written to out_model if given) when the
// feature is one the KPI manager computes: on an error target as ErrorModel::conditional (offsets
// into the means), on detection as ClassModel::detection_conditional (offsets into
// detection_probability of the range bin, clamped to [0, 1]). "after_simulated" is the same RMS
// with what the KPI manager really uses with each fold's refitted model per held-out truth object
// — the conditional mean error (noise off, ground-truth velocities by differences) or the
// detection probability — and "before_simulated" with each fold's base.
// Greedy over targets: once the top one is added as a term, the best bias form of each other
// target (features the KPI manager computes) is judged the same way, in order of score, and added
// when it passes, at most one per target and max_effects in all. Such a further error term is kept only for
// the classes whose re-simulated held-out distribution of the KPI (object_distribution.h) does not
// get worse and whose own held-out residual falls, rejected when no class keeps it (the noise is
// shrunk for it, object_terms.h). "added_effects" lists each with
// its own before -> after, "after_simulated" with the model carrying all of them. The single-effect
// fields ("added_effect", "before", "after", ...) describe the top one.
// "candidates" lists every feature x target x form with its "decision" and a "reason" in words a
// user acts on, recorded when the decision is made (object_loop.h ObjectLoopResult, the typed
// result the JSON is written from).
nlohmann::json loop_objects(const TrackingData& data, const LoopOptions& options = {});

}  // namespace lidarsim::qualify
