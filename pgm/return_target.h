#pragma once
// Which empty cells of a measured scan had geometry: the training target of the return model.
//
// A cell without a return is either sky (the beam met nothing within the sensor's reach) or a
// dropped return (it met a surface that sent back too little light: dark or glossy paint, glass,
// wet road, grazing incidence). A scan does not say which; this rule decides from the scan's own
// structure, in this order (the first that applies wins):
//
//  0. own vehicle: in a row whose ground lies within `vehicle_ground_m`, a run of at least
//     `vehicle_run` empty columns is the sensor's own vehicle hiding the ground (KITTI's lowest
//     lasers see nothing straight ahead and behind): no scene geometry, labelled Sky. Near ground
//     returns strongly, so random drops do not make such runs.
//  1. row gap: the nearest returns to the left and right in the same row lie at most
//     `row_gap` columns away and their ranges differ by at most `similar_range` (relative):
//     the beam swept one surface, so the gap is a drop. Range = linear interpolation of the
//     two; class = the nearer one's (the left one's on a tie).
//  2. below a return: a return exists higher up in the same column, and the next return below
//     (if any) lies no farther horizontally than it (+ `similar_range`). Surfaces stand on the
//     ground, so a lower beam meets that surface, something in front of it, or the ground; a
//     return below that lies beyond the one above means the beams in between passed under an
//     overhang (a canopy, a bridge), so they are left to rule 3.
//     Range = the nearer of the ground range (rule 3) and the range at which the beam reaches the
//     horizontal distance of the nearest return above (a vertical surface); class = that return's
//     class when the surface is nearer, else the ground class (below).
//  3. ground: the beam points below the horizon and meets the level ground plane, at the
//     sensor's height below it, within `ground_reach_share` of the scan's reach.
//     Range = h / sin(-elevation); class = the class of the nearest return below in the same
//     column, else above, else unlabeled.
//  4. otherwise sky: above the topmost return of its column with no ground within reach.
//
// The sensor height comes from the scan (estimate_sensor_height) unless given; the reach is a
// high quantile of the scan's return ranges unless given. Elevations are the layout's nominal
// row elevations; the ground is assumed level in the sensor frame.
//
// Known errors (docs/returns.md measures them on synthetic scans and names the real cases):
//  - a beam that passes under a canopy or an overhang into open space is counted as a drop by
//    rule 2 when its column has no return below it (every lower beam dropped or out of reach);
//  - ground falling away (downhill, an embankment's edge) beyond the reach is counted as a drop by
//    rule 3; ground rising (uphill) is right, only its estimated range is too long;
//  - a whole run of more than `row_gap` dropped columns on a surface above the horizon with sky
//    above it (a dark car's roof line against the sky) is counted as sky;
//  - the range and class of a drop are estimates (interpolated or predicted), not measurements;
//  - a dark object right beside the vehicle that drops a run of `vehicle_run` columns on a near
//    ground row is taken for the vehicle (rule 0).
#include <cstdint>
#include <vector>

#include "pgm/polar_grid_map.h"

namespace lidarsim::pgm {

// Sky = no scene geometry within reach (the sky, or the sensor's own vehicle: rule 0).
enum class ReturnLabel : std::uint8_t { Return = 0, Drop = 1, Sky = 2 };

// Which rule labelled a cell (for reports and tests).
enum class ReturnRule : std::uint8_t { Measured = 0, RowGap = 1, BelowReturn = 2, Ground = 3, Sky = 4, Vehicle = 5, count = 6 };
const char* to_string(ReturnRule rule);

struct ReturnTargetOptions {
  double sensor_height_m = 0;      // height of the sensor above the ground; 0 = estimated from the scan
  double reach_m = 0;              // farthest range the sensor reaches; 0 = reach_quantile of the returns
  double reach_quantile = 0.999;   // of the scan's return ranges
  double ground_reach_share = 0.8; // rule 3 only where the ground range is within this share of the reach
  int row_gap = 6;                 // rule 1: at most this many columns between the bracketing returns
  double similar_range = 0.1;      // rule 1: |r_left - r_right| <= this * min(r_left, r_right)
  int vehicle_run = 32;            // rule 0: empty columns in a run (0 = off)
  double vehicle_ground_m = 8;     // rule 0: only rows whose ground range is within this
};

struct ReturnTarget {
  int rows = 0, cols = 0;
  std::vector<ReturnLabel> label;  // [rows * cols]
  std::vector<ReturnRule> rule;    // [rows * cols]
  std::vector<float> range;        // measured (Return) or estimated (Drop) range, m; 0 for sky
  std::vector<int> class_id;       // measured (Return) or imputed (Drop) class; 0 for sky
  double sensor_height_m = 0, reach_m = 0;
  long long returns = 0, drops = 0, sky = 0;
  long long by_rule[static_cast<int>(ReturnRule::count)] = {};
};

// Needs the channels "range", "mask" and "class"; uses "height" (sensor-frame z) when present.
// Throws lidarsim::Error when a channel is missing, or the sensor height is neither given nor
// estimable (too few returns on the lower beams).
ReturnTarget return_target(const PolarGridMap& pgm, const ReturnTargetOptions& options = {});

// Height of the sensor above the ground from the returns of the lower beams (elevation below
// half the lowest beam's and below -3 deg): the most common value of -z (the densest 2 cm bin in
// 0.2-5 m near the densest +-10 cm window), refined by the median within 10 cm of it, since the ground is the
// surface the lower beams meet most. Returns 0 when fewer than 50 such returns exist. On KITTI
// the ground of the lower beams spreads over 1.5-2.0 m (pitch, crown, kerbs): the estimate is
// that spread's densest part, not the mount's 1.73 m.
double estimate_sensor_height(const PolarGridMap& pgm);

}  // namespace lidarsim::pgm
