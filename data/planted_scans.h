#pragma once
// Planted intensity effects on measured geometry: the intensity half of the loop's campaign of
// random planted effects. The geometry (range, class, material, incidence, azimuth,
// rows) of real scans is kept; the measured intensity is replaced by
//
//   target = base(class, range) x gain(effect, cell) + N(0, sigma^2)
//
// base is a HIDDEN model drawn per draw: an albedo per class (uniform 0.15-0.6) times a range
// fall-off exp(-r / L) (L uniform 60-150 m), with r the centre of the cell's 5 m range bin
// (data::range_bin, the bins of the loop's lookup base). It is a function of class and range only,
// and binned so that the loop's lookup base (class x 5 m range bins) can represent it exactly: with
// the smooth fall-off (binned = false) the lookup leaves the fall-off inside each bin, up to 8 %
// of the albedo at L = 60 m, which correlates with elevation on the ground and made the loop add
// "elevation" on noise-free controls; the campaign tests the loop on planted effects, not the
// lookup's bin width. sigma is known, so the loop's held-out RMSE can be turned into the error
// against the noise-free truth: excess = sqrt(max(0, rmse^2 - sigma^2)). What excess remains on a
// control is the lookup's own estimation error (class x bin keys with few or no fit cells).
//
// One planted effect per draw, parameters drawn at random from the draw's seed. Families and the
// loop feature (qualify/intensity/intensity.h kIntensityFeatures) that names each:
//   beam_gain          gain per laser 1 + s u, u uniform -1..1, spread s 0.1-0.5      beam_row
//   bad_lasers         2-10 lasers at 0.3-0.8 x                                       beam_row
//   azimuth_window     0.4-0.8 or 1.25-2 x over a window 20-120 deg wide, anywhere    azimuth
//   range_falloff      (range / 10 m)^-k, |k| 0.2-0.6, on a block of adjacent lasers  beam_row
//                      (25-50 % of the rows, anywhere), k of either sign              (or elevation)
//   incidence_falloff  cos(incidence)^k, k 0.3-1.2 (base has no incidence term)       incidence_angle
//   class_gain         one class (>= 2 % of the returns) 0.5-0.8 or 1.25-1.6 x        (absorbed)
//   control            nothing
//
// Why range_falloff is on a block of lasers: range is a key of the loop's base, so a fall-off
// change common to every cell is refitted away by the base (class x range bins hold it) and there
// is nothing left to find; what the base cannot represent is a fall-off that differs between
// lasers (receiver optics focused differently per laser block, as on stacked-head sensors). The
// cells it changes are a set of rows, so the loop names it by beam_row, or by elevation (a
// contiguous block of lasers is an elevation band: both names count). A near-range change below
// the first 5 m bin was considered and left out: on a roof-mounted sensor only the lowest lasers
// see the ground that close, so it is again a per-laser effect, and the loop's vocabulary would
// name "range", a feature its base claims and never ranks.
// Why class_gain is scored as "absorbed": class is a key of the base too, so one class's gain is
// in both the fit and the held-out cells and the refitted lookup holds it exactly. The right
// answer is to add nothing; a draw counts when nothing is added. (A UNet base conditioned on class
// absorbs it the same way.)
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/dataset.h"

namespace lidarsim::data {

enum class PlantedScanFamily { BeamGain, BadLasers, AzimuthWindow, RangeFalloff, IncidenceFalloff, ClassGain, Control };
const std::vector<PlantedScanFamily>& all_planted_families();
std::string to_string(PlantedScanFamily family);
PlantedScanFamily planted_scan_family_from_string(const std::string& name);  // throws naming the known ones

// How a family is scored: Detect = the loop must name the planted feature and cut the excess
// error to <= 0.7 x; Absorbed = the base already represents it, nothing may be added; Control =
// anything added is a false add.
enum class PlantedScoring { Detect, Absorbed, Control };
std::string to_string(PlantedScoring scoring);

struct HiddenIntensityBase {
  std::vector<double> albedo;  // per class id (pgm::cls)
  double attenuation_m = 100;  // range fall-off exp(-range / attenuation_m)
  double sigma = 0.03;         // Gaussian noise added to every return
  bool binned = true;          // fall-off at the 5 m range bin's centre (see the top of the file)
  double operator()(int class_id, double range_m) const;
};

struct PlantedScanEffect {
  PlantedScanFamily family = PlantedScanFamily::Control;
  PlantedScoring scoring = PlantedScoring::Control;
  std::string feature;                // the loop's name for it; empty when nothing is to be named
  std::vector<std::string> accepted;  // names that count as naming it (feature first)
  std::vector<double> row_gain;       // BeamGain, BadLasers: gain per row (1 elsewhere)
  double gain = 1;                    // AzimuthWindow, ClassGain
  double azimuth_start_deg = 0, azimuth_width_deg = 0;  // [start, start + width) mod 360, azimuth = atan2(y, x)
  int row_first = 0, row_last = -1;   // RangeFalloff: rows changed, inclusive
  double exponent = 0;                // RangeFalloff: (range / reference)^-exponent; IncidenceFalloff: cos^exponent
  double reference_range_m = 10;
  int class_id = -1;                  // ClassGain
  nlohmann::json parameters;          // as drawn, for the record
  // The multiplicative gain of a cell.
  double gain_at(int row, double range_m, double azimuth_rad, double incidence_rad, int class_id) const;
};

struct PlantedScanDraw {
  PlantedScanFamily family = PlantedScanFamily::Control;
  std::uint64_t seed = 0;
  HiddenIntensityBase base;
  PlantedScanEffect effect;
  nlohmann::json to_json() const;  // family, seed, scoring, feature, accepted, parameters, base
};

// Draws the hidden base and one effect of `family` from `seed` (same seed, same draw). `geometry`
// gives the row count and the class shares (class_gain picks among classes with >= 2 % of returns).
PlantedScanDraw draw_planted(PlantedScanFamily family, std::uint64_t seed, const Dataset& geometry, double sigma = 0.03,
                         bool binned_base = true);

// `geometry` with its target replaced by the draw's intensity on every cell with a return (0
// elsewhere); the noise comes from the draw's seed. Needs the range, class, azimuth and incidence
// channels (the error names the missing one). noise = false gives the noise-free truth.
Dataset plant(const Dataset& geometry, const PlantedScanDraw& draw, bool noise = true);

// One draw scored from the loop's JSON (qualify::loop_intensity: added_effect, rmse_before,
// rmse_after). Excess errors are against the noise-free truth: sqrt(max(0, rmse^2 - sigma^2)).
//
// `floor` is the excess the loop's base leaves without any effect: the excess_before of the draw's
// control twin (draw_planted(Control, same seed): the same hidden base and the same noise, no
// effect). On the three SemanticKITTI scans it is 0.02-0.045, nearly all from classes found only
// in the held-out regions (fence, other-structure), which the lookup can only give the global mean.
// That error is the base's, in before and after alike, so the rule "after <= 0.7 x before" can fail
// on a correct, complete correction. The score therefore also reports the excess above the floor,
// sqrt(max(0, excess^2 - floor^2)), and the same rule on it (hit_above_floor).
struct PlantedScore {
  std::string added;          // the loop's added_effect, empty when none
  bool named = false;         // added is one of the accepted names
  bool cut = false;           // excess_after <= 0.7 x excess_before
  bool hit = false;           // Detect: named && cut; Absorbed: nothing added; Control: nothing added
  bool false_add = false;     // something added that is not the planted feature (any add on a control)
  double excess_before = 0, excess_after = 0;
  double floor = 0, above_floor_before = 0, above_floor_after = 0;
  bool hit_above_floor = false;  // as hit, with the 0.7 x rule on the excess above the floor
};
inline constexpr double kPlantedErrorRatio = 0.7;
PlantedScore score_planted(const PlantedScanDraw& draw, const nlohmann::json& loop, double floor = 0);

}  // namespace lidarsim::data
