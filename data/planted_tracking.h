#pragma once
// Planted effects on real ground truth (the object loop's campaign of random planted effects): a
// KITTI tracking folder whose labels and calibration are real KITTI tracking ground truth (a few
// sequences of ../shared/data/kitti-tracking-gt-pointrcnn, optionally a window of frames of each)
// and whose detections (detection/pointrcnn_{Car,Pedestrian,Cyclist}_val/NNNN.txt, AB3DMOT layout)
// come from a hidden base model plus ONE planted effect with random parameters. The loop
// (qualify/objects/objects.h loop_objects) is then run blind on it and scored against the draw's truth.
//
// Base model (what the KPI model can represent): per class Gaussian errors along and across the
// line of sight, of length, width, height and heading, each with its own sigma; a detection
// probability per class that falls with the occlusion level; false positives per frame and class,
// placed by independent draws of range and azimuth (azimuth within where the objects are).
// Only truth of the exact types Car, Pedestrian and Cyclist is detected.
//
// Families (parameters drawn at random per draw; the effect's loop feature and target in brackets):
//   lag              position error = -lag x the truth's velocity relative to the sensor (central
//                    differences at 10 Hz, as the loop computes it), lag 0.05-0.3 s
//                    [radial_velocity, position_along]
//   aspect_size      length measured short seen end-on (share x length x (1 - aspect)), or width
//                    short seen side-on (share x width x aspect), aspect = heading relative to the
//                    line of sight folded to [0, 1]; share 0.1-0.3 [heading_to_line_of_sight, length|width]
//   annotation_size  length or width short by the label's occlusion level (0..3) or truncation
//                    (clamped to [0, 1]): share x level x size, share 0.08-0.2 per level (at most
//                    0.6 in all) [occlusion|truncation, length|width]
//   spread           the sigma of the error along or across the line of sight x (1 + gain x
//                    speed / 10 m/s) or (1 + gain x range / 40 m), gain 1.5-4 [speed|range, position_*]
//   azimuth_dropout  detection probability x 0-0.3 inside an azimuth window 15-40 deg wide placed
//                    anywhere within the 5-95 % azimuths of the objects [azimuth, detection]
//   range_dropout    detection probability x 0-0.3 beyond a range drawn between the 40 % and 80 %
//                    ranges of the objects [range, detection]
//   class_bias       for one class only (one with >= 300 truth boxes), a bias of one error
//                    (position_along, position_across, length, width or heading) linear in a
//                    feature (speed, heading relative to the line of sight, or azimuth), from
//                    -amplitude/2 to +amplitude/2 over the feature's span, amplitude 4-8 x that
//                    class's sigma. A constant per-class bias is what the base model holds already.
//                    [speed|heading_to_line_of_sight|azimuth, the error]
//   fp_cell          extra false positives of one class, 0.3-1 per frame, in a cell of range
//                    (5-15 m deep, starting at 5-40 m) x azimuth (10-30 deg wide, within the objects'
//                    azimuths) [range or azimuth, false_positives]
//   control          none ["", ""]
#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "sensor/kpi_model.h"

namespace lidarsim::data {

enum class PlantedFamily { Lag, AspectSize, AnnotationSize, Spread, AzimuthDropout, RangeDropout, ClassBias, FpCell,
                           Control };
inline constexpr int kPlantedFamilies = 9;
inline constexpr std::array<const char*, kPlantedFamilies> kPlantedFamilyNames = {
    "lag",           "aspect_size", "annotation_size", "spread", "azimuth_dropout",
    "range_dropout", "class_bias",  "fp_cell",         "control"};
static_assert(kPlantedFamilyNames.size() == static_cast<size_t>(PlantedFamily::Control) + 1);
std::string to_string(PlantedFamily f);
PlantedFamily planted_family_from_string(const std::string& name);  // throws naming the valid names

// The loop's target of extra false positives (not one of qualify/objects/objects.h kObjectTargets).
inline const std::string kFalsePositivesTarget = "false_positives";

struct PlantedSequence {
  std::string name;     // the source sequence ("0011"), written under the same name
  int first_frame = 0;  // the window's first source frame, written as frame 0
  int frames = 0;       // frames in the window
};

// Per class, indexed like sensor::kModelledClasses (Car, Pedestrian, Cyclist).
struct PlantedBaseModel {
  using PerClass = std::array<double, sensor::kModelledClassCount>;
  PerClass along{}, across{}, length{}, width{}, height{}, heading{};  // sigmas, m and rad
  PerClass detection{};               // probability at occlusion level 0
  double occlusion_loss = 0.1;        // detection probability x (1 - loss x level), level capped at 2
  PerClass fp_rate{};                 // false positives per frame
};

struct PlantedEffect {
  PlantedFamily family = PlantedFamily::Control;
  std::string feature;                    // the loop's feature the effect depends on ("" for control)
  std::vector<std::string> features;      // every feature that names it (fp_cell: range and azimuth)
  std::string target;                     // the loop's target (kObjectTargets or kFalsePositivesTarget)
  std::map<std::string, double> params;   // the drawn parameters, units in the names
};

struct PlantedDraw {
  std::filesystem::path source;  // the real KITTI tracking folder
  std::uint64_t seed = 1;
  std::vector<PlantedSequence> sequences;
  PlantedBaseModel base;
  PlantedEffect effect;
  // What the effect's parameters were drawn within (the objects of the chosen windows).
  double azimuth_lo = 0, azimuth_hi = 0;  // rad, 5 % and 95 % azimuths
  double range_lo = 0, range_hi = 0;      // m, 40 % and 80 % ranges
};

struct PlantedTrackingOptions {
  std::filesystem::path source;  // label_02/, calib/ (and evaluate_tracking.seqmap.val, not needed)
  int sequences = 2;             // how many, drawn among those with >= kPlantedMinTracks tracks
  int max_frames = 300;          // window of frames per sequence (0: the whole sequence)
  std::uint64_t seed = 1;
};
inline constexpr int kPlantedMinTracks = 15;  // of Car, Pedestrian and Cyclist in the window

// Draws the sequences, their windows, the base model and the effect's parameters (deterministic in
// the seed). Errors: the source folder or its label_02/ missing, fewer usable sequences than asked.
PlantedDraw plan_planted_tracking(PlantedFamily family, const PlantedTrackingOptions& options);

// What an ideal refit of the planted effect could reach on the written detections: the RMS of the
// planted target's error centred per class with the effect (before) and without its part (after);
// detection: detected 0/1 minus the class x occlusion level's detection rate (before) and minus the
// true detection probability (after). NaN for spread, fp_cell and control. A draw whose ideal
// after / before is above the campaign's 0.7 cannot be recalled however well the loop finds it.
struct PlantedStats {
  double ideal_before = std::numeric_limits<double>::quiet_NaN();
  double ideal_after = std::numeric_limits<double>::quiet_NaN();
};

// The hidden generating model (base + plant) at one truth object, for scoring a refitted model
// against the truth instead of against noisy outcomes (bench/campaign_objects.h truth_score). The
// object is described by what the loop's features hold (qualify/objects/objects.h kObjectFeatures),
// computed from the written labels as the generator computes them.
struct PlantedObject {
  int cls = 0;                  // index in sensor::kModelledClasses
  double range = 0, azimuth = 0;  // BEV m, atan2(y, x) rad
  double radial_velocity = 0, speed = 0;  // m/s: velocity along the line of sight, its norm
  double aspect = 0;            // heading to the line of sight folded to [0, 1] (0 end-on)
  double occlusion = 0, truncation = 0;  // the label's level (0..3) and truncation in [0, 1]
  double length = 0, width = 0;  // the truth box's, m
};
// The mean of `target`'s error (the base's errors are zero-mean: the plant's part only).
double planted_mean_error(const PlantedDraw& d, const std::string& target, const PlantedObject& o);
// The detection probability (base x occlusion x the planted dropout).
double planted_detection_probability(const PlantedDraw& d, const PlantedObject& o);
// The sigma of `target`'s error (the base's, x the planted growth for the spread family); NaN for
// a target the base has no sigma of.
double planted_sigma(const PlantedDraw& d, const std::string& target, const PlantedObject& o);

// Writes DIR/label_02, DIR/calib, DIR/detection/pointrcnn_<Class>_val and DIR/evaluate_tracking.seqmap.val.
PlantedStats write_planted_tracking(const std::filesystem::path& dir, const PlantedDraw& draw);

}  // namespace lidarsim::data
