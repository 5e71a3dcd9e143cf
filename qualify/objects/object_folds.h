#pragma once
// The object loop's cross-fit data (internal to qualify/): small helpers shared by the object
// files, a target's residuals under a fold's base model, and the folds themselves (base model
// fitted on the fold's fit sequences; residuals of every target on fit and held-out sequences).
// fit_idx and held_idx are disjoint sets of sequences (of the loop's data, or of its time blocks,
// split_into_time_blocks, each a sequence of its own), so a track is always entirely on one side.
#include <array>
#include <limits>
#include <string>
#include <vector>

#include "qualify/objects/objects.h"
#include "qualify/residual.h"
#include "sensor/kpi_fit.h"
#include "sensor/kpi_model.h"

namespace lidarsim::qualify::obj {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
inline constexpr sensor::KpiParam kTargetParam[6] = {
    sensor::KpiParam::PositionAlong, sensor::KpiParam::PositionAcross, sensor::KpiParam::Length,
    sensor::KpiParam::Width,         sensor::KpiParam::Height,         sensor::KpiParam::Heading};

double wrap(double a);  // to [-pi, pi)
int class_index(sensor::ObjectClass c);  // 0 Car, 1 Pedestrian, 2 Cyclist, else -1
int feature_index(const std::string& name);  // in kObjectFeatures; throws when absent
std::string target_unit(const std::string& target);  // for axis labels
double rms(const std::vector<double>& v);

// Residuals of one target and the records they belong to (pointers into a Fold's ObjectSets).
struct Split {
  std::vector<double> r;
  std::vector<const ObjectRecord*> rec;

  std::vector<double> column(int f) const;
  std::vector<int> classes() const;
  std::vector<int> tracks() const;  // one id per (sequence, track): the bootstrap's blocks
  // The model's own cell of each record for target t: range bin (error means), or range bin x
  // visibility bin (detection probability).
  std::vector<int> cells(int t, int nvis) const;
  std::vector<double> clipped(const Winsor& w) const;
};

// Residual of one record for one target under a base model; NaN when not defined.
double base_residual(const sensor::KpiModel& base, const ObjectRecord& r, int t);

// One side of the cross-fit: the base model fitted on fit_idx, the residuals of every target on
// its own sequences (to fit the term) and on held_idx (to judge it).
struct Fold {
  std::vector<int> fit_idx, held_idx;
  sensor::KpiModel base;
  ObjectSet fit_set, held_set;
  std::vector<Split> fit_r, held_r;  // per target
  std::vector<Winsor> win;           // per target, from the fit residuals
  // fit_effect shrinks the bias forms fitted on this fold by their track-bootstrap uncertainty
  // (object_terms.h shrink_by_track_bootstrap); off: the fitted values as they are.
  TermShrink shrink_terms = TermShrink::Off;
  // Set before make_fold: the base model's per-track constants partially pooled across classes
  // (pool_track_spread).
  bool pool_track_spread = false;
  std::vector<std::array<double, 3>> track_spread_factor;  // what it applied: [class][length, width, height]
};

// The size errors' per-track constant (track_std) of a class with few tracks is poorly known: its
// ratio to the within-track noise (sigma, RMS over range bins) is partially pooled across classes
// on the log scale (empirical Bayes: sampling variance 1 / (2 (T - 1)) for T tracks with >= 3
// detected frames in `fit`; prior mean and variance by moments over the classes), and track_std
// set to sigma x the pooled ratio. Returns per class and size parameter the factor applied.
std::vector<std::array<double, 3>> pool_track_spread(sensor::KpiModel& m, const ObjectSet& fit);

Split gather(const ObjectSet& s, const sensor::KpiModel& base, int t);

// Built in place: the Splits point into the fold's own ObjectSets.
void make_fold(Fold& k, const TrackingData& data, std::vector<int> fit_idx, std::vector<int> held_idx,
               const sensor::FitOptions& opt);

std::vector<std::string> names_of(const TrackingData& data, const std::vector<int>& idx);

// Features fixed to the sensor: an effect on them (a soiled patch of the window, a weak laser)
// is the same in every place and at every time, so folds may be blocks of time within a
// sequence. Every other feature can depend on the place or the time (traffic, road, weather)
// and is judged on folds of whole sequences. Range is fixed to the sensor too (a detection edge,
// a spread that grows with distance), and the base model's range bins leave what lies between
// their edges to the loop (object_candidates.h used_by_model).
inline const std::vector<std::string> kSensorFixedFeatures = {"azimuth", "range"};
bool fixed_to_sensor(const std::string& feature);

// Time-block folds, used for the features fixed to the sensor when the data has at most
// kTimeFoldsMaxSequences sequences (then one side of the even/odd split holds a single sequence,
// and a local effect fitted on one sequence's tracks does not carry to another's).
inline constexpr int kTimeFoldsMaxSequences = 3;
inline constexpr int kTimeBlocks = 4;  // per sequence

// Each sequence cut into `blocks` blocks of time, each a sequence of its own (block b of
// sequence s at s * blocks + b). A track (of the three modelled classes) goes whole into one
// block: tracks ordered by their middle frame, `blocks` contiguous runs of equal count. A block
// keeps every frame of its sequence, its own tracks' truths with the detections matched to them
// on the whole sequence (sensor::match_truth_to_detections, opt's gate and score), the other
// ground truth (Van, ...) and the detections matched to no truth, so its records equal the
// whole sequence's records of its tracks.
struct TimeBlocks {
  TrackingData data;        // names "<sequence> block <b + 1>/<blocks>"
  std::vector<int> origin;  // per block: its sequence in the data it was cut from
  std::vector<int> block;   // per block: 0 .. blocks - 1 (even blocks form one side, odd the other)
};
TimeBlocks split_into_time_blocks(const TrackingData& data, int blocks = kTimeBlocks,
                                  const sensor::FitOptions& opt = {});
// The two sides of the time-block cross-fit: the even blocks of every sequence, the odd ones.
std::array<std::vector<int>, 2> time_block_sides(const TimeBlocks& tb);

}  // namespace lidarsim::qualify::obj
