#pragma once
// A synthetic "reference sensor": writes recorded-format data (exactly the layouts the readers
// take from real sensors) with switchable effects that the simulation models do not declare, so
// the closed loop (qualify/) can be tested on data whose hidden effect is known.
//
// Objects (KITTI tracking layout): DIR/label_02/NNNN.txt, DIR/calib/NNNN.txt,
// DIR/detection/pointrcnn_{Car,Pedestrian,Cyclist}_val/NNNN.txt (AB3DMOT layout) and
// DIR/evaluate_tracking.seqmap.val. Tracks move at constant velocity relative to the sensor;
// detections = truth + small Gaussian errors (along/across the line of sight, size, heading),
// a constant detection probability, a few false positives per frame, plus the effect:
//   velocity_lag      position error = -lag * velocity (a latency): along the line of sight
//                     -lag * radial velocity
//   truncation_size   length error = -0.45 * truncation * length (a truncated box is measured short)
//   occlusion_size    length error = -kOcclusionSizeShare * occlusion level * length (an occluded box is
//                     measured short; levels 0, 1, 2): a bias on an error's mean by the occlusion
//                     annotation, which the KPI model conditions on only in detection and the errors'
//                     spread (feature: occlusion)
//   aspect_across     across error grows with the heading relative to the line of sight
//   azimuth_dropout   a soiled left part of the sensor window (road spray the wiper does not
//                     reach): detection probability x 0.2 for objects whose box centre lies at
//                     azimuth atan2(y, x) >= 20 deg in the sensor frame (front left and beyond);
//                     elsewhere, and all errors, as without effect. A condition on detection,
//                     not on an error (feature: azimuth). One edge only: the loop's equal-count
//                     bins blur a sharp edge, and the tracks thin out at large azimuth.
//   azimuth_window_dropout  detection probability x 0.2 in a window of azimuth with two edges,
//                     [window_azimuth_lo, window_azimuth_hi] (default [kWindowAzimuthLo,
//                     kWindowAzimuthHi]: a patch of dirt on the front right of
//                     the window); elsewhere as without effect (feature: azimuth).
//   aspect_spread     the error across the line of sight gets noisier the more the box is seen
//                     side-on: its noise is multiplied by kSpreadBase + kSpreadPerAspect x the
//                     heading relative to the line of sight folded to [0, 1] (0 end-on, 1
//                     side-on); its mean stays 0 (feature: heading_to_line_of_sight).
// Intensity (SemanticKITTI layout): DIR/sequences/00/velodyne/NNNNNN.bin + labels/NNNNNN.label.
// A 64-beam HDL-64E-like scan in firing order (ring by ring, azimuth rising from -pi to pi) of a
// flat ground (road, sidewalk) inside a ring of random wall facets (building, fence,
// vegetation); intensity = class albedo x effect + Gaussian noise, with the effect:
//   incidence   x cos(incidence angle) (true facet normal)
//   height      x (0.6 + 0.3 (z + sensor height))
//   azimuth     x (1 + 0.5 sin(azimuth))
//   beam_gain   x a gain per laser (beam row): 1 + beam_gain_spread u, u in [-1, 1] fixed per
//               laser (a per-laser calibration error; spread 0.4 by default)
//   azimuth_window  x window_gain (0.5) for azimuth in [window_azimuth_lo, window_azimuth_hi]
//               (default [kIntensityWindowAzimuthLo, kIntensityWindowAzimuthHi]: a window of the
//               split variable itself that covers one guarded validation region, its guard and a
//               strip of training columns on one side)
// "none" is the control: no hidden effect in either domain.
#include <cstdint>
#include <filesystem>
#include <string>

namespace lidarsim::data {

enum class ObjectEffect { None, VelocityLag, TruncationSize, AspectAcross, AzimuthDropout, AzimuthWindowDropout, AspectSpread,
                          FalsePositiveHotspot, OcclusionSize };
enum class IntensityEffect { None, Incidence, Height, Azimuth, BeamGain, AzimuthWindow };
inline constexpr double kIntensityWindowAzimuthLo = 0.3, kIntensityWindowAzimuthHi = 2.2;  // rad, atan2(y, x)
// beam_gain's gain of laser `row`.
double reference_beam_gain(int row, double spread = 0.4);

std::string to_string(ObjectEffect e);     // "none", "velocity_lag", ...
std::string to_string(IntensityEffect e);  // "none", "incidence", ...
// The loop's feature name the effect depends on ("" for none).
std::string effect_feature(ObjectEffect e);
std::string effect_feature(IntensityEffect e);

// azimuth_dropout's sector [lo, hi] (rad, sensor frame) and the factor on the detection probability in it.
inline constexpr double kDropoutAzimuthLo = 20 * 3.14159265358979323846 / 180;
inline constexpr double kDropoutAzimuthHi = 3.14159265358979323846;  // to the back: no upper edge
inline constexpr double kDropoutFactor = 0.2;
// azimuth_window_dropout's window (rad): both edges inside the tracks' azimuth range.
inline constexpr double kWindowAzimuthLo = -35 * 3.14159265358979323846 / 180;
inline constexpr double kWindowAzimuthHi = -15 * 3.14159265358979323846 / 180;
// occlusion_size: the share of the length lost per occlusion level.
inline constexpr double kOcclusionSizeShare = 0.2;
// aspect_spread: noise across the line of sight x (kSpreadBase + kSpreadPerAspect * aspect in [0, 1]).
inline constexpr double kSpreadBase = 0.3;
inline constexpr double kSpreadPerAspect = 2.4;

// fp_hotspot: the spot (rad, m) and its extra false positives per frame.
inline constexpr double kFpHotspotAzimuthLo = -35 * 3.14159265358979323846 / 180;
inline constexpr double kFpHotspotAzimuthHi = -15 * 3.14159265358979323846 / 180;
inline constexpr double kFpHotspotRangeLo = 15, kFpHotspotRangeHi = 25;
inline constexpr double kFpHotspotRate = 0.6;
// Ghost tracks (ReferenceTrackingOptions::ghost_survival): extra Car false positives per frame on
// average, placed as polar_clutter, each moving by this jitter per frame (m, per axis).
inline constexpr double kFpGhostRate = 0.6;
inline constexpr double kFpGhostJitter = 0.05;

struct ReferenceTrackingOptions {
  ObjectEffect effect = ObjectEffect::None;
  ObjectEffect second_effect = ObjectEffect::None;  // planted as well (give it a different target)
  int sequences = 2;
  int frames = 200;
  int tracks = 24;          // per sequence
  double noise = 0.1;       // m (positions), size noise = noise / 2, heading noise = noise / 5 rad
  double detection_probability = 0.95;
  double false_positives = 0.2;  // per frame
  // Clutter placed by independent draws of range (5-60 m), azimuth (-45 to 45 deg) and score, which the
  // KPI model's independent quantiles hold exactly; default: uniform in a rectangle ahead (x 5-60 m,
  // y -20 to 20 m), where range and azimuth depend on each other.
  bool polar_clutter = false;
  // Planted ghost tracks (what the loop's false-positive persistence must find): kFpGhostRate extra
  // Car false positives per frame, each reported again the next frame with this probability (same
  // place up to kFpGhostJitter, same score), births at kFpGhostRate x (1 - survival); 0: none.
  // Drawn from a stream of its own, so nothing else moves.
  double ghost_survival = 0;
  // azimuth_window_dropout's window (rad, atan2(y, x) in the sensor frame).
  double window_azimuth_lo = kWindowAzimuthLo, window_azimuth_hi = kWindowAzimuthHi;
  std::uint64_t seed = 1;
};
void write_reference_tracking(const std::filesystem::path& dir, const ReferenceTrackingOptions& options);

struct ReferenceScanOptions {
  IntensityEffect effect = IntensityEffect::None;
  int scans = 3;
  int columns = 1024;  // azimuth steps per ring
  double noise = 0.02;
  double beam_gain_spread = 0.4;  // beam_gain: gain 1 + spread u per laser
  // azimuth_window: the window (rad, atan2(y, x)) and the gain inside it.
  double window_azimuth_lo = kIntensityWindowAzimuthLo, window_azimuth_hi = kIntensityWindowAzimuthHi;
  double window_gain = 0.5;
  std::uint64_t seed = 1;
};
void write_reference_semantickitti(const std::filesystem::path& dir, const ReferenceScanOptions& options);

}  // namespace lidarsim::data
