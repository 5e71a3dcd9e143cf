#pragma once
// Points -> Polar Grid Map, and predictions back to points.
//
// Column = layout.column_of(x, y). Row, by RowMode:
//  - FiringOrder: for scans stored in firing order ring by ring with no ring index (KITTI
//    HDL-64E .bin files): a new row starts where the azimuth wraps around, i.e. drops by more
//    than pi from the last regular point of the current row. A point that jumps *up* by more
//    than pi (a straggler measured just before the wrap but stored just after it) stays in the
//    current row and is not used as reference, so it cannot start a spurious row. Used only when
//    the cut gives exactly layout.rows() rows; the i-th cut row is layout row i.
//  - NearestElevation: row of the nearest beam elevation (layout.nearest_row). For clouds not
//    in firing order (simulated, shuffled, filtered, or a scan with missing rings). Rows of real
//    KITTI scans overlap by about 1 deg in elevation, so this is the fallback, not the default.
//  - Ring: the point's own ring index (Point::ring), for sensors that record one.
//  - Auto: Ring when every point has one; else FiringOrder when it yields exactly layout.rows()
//    rows; else NearestElevation. ProjectionResult::row_mode says which was used.
//
// Each cell keeps the nearest return (smallest range; ties keep the earlier point). Points that
// lose that contest are not in the grid, but back_project() still gives them the value of the
// cell they fell into, so every point gets a prediction.
#include <cstdint>
#include <string>
#include <vector>

#include "pgm/polar_grid_map.h"

namespace lidarsim::pgm {

struct Point {
  float x = 0, y = 0, z = 0;  // sensor frame, metres (x forward, y left, z up)
  float intensity = 0;        // measured reflectance/intensity (0 when unknown)
  int class_id = 0;           // pgm::cls id
  int material_id = 0;        // pgm::material id
  int ring = -1;              // beam index when the sensor records it (row 0 = top), else -1
};

enum class RowMode { Auto, FiringOrder, NearestElevation, Ring };
std::string to_string(RowMode mode);

// Channels every projection writes; more can be asked for by name (see kEffectChannels).
inline const std::vector<std::string> kBaseChannels = {"range", "class", "material", "intensity", "mask"};
// Optional geometric channels: elevation and azimuth of the point (rad), height = z (m),
// incidence = angle between the beam and the surface normal estimated from the points of the
// neighbouring cells (rad, 0 = head-on; cells without a neighbour in both the row and the column
// direction get 0; columns wrap around), x, y, z (m), depth_discontinuity = 1 next to an
// occlusion edge (the left or right neighbour in the row has a return more than 10 % nearer or
// farther; columns wrap around), else 0. Rows are not compared: on the ground adjacent beams are
// metres apart at range, which would make it a second incidence estimate rather than an edge flag.
inline const std::vector<std::string> kEffectChannels = {"elevation", "azimuth", "height", "incidence",
                                                         "x",         "y",       "z",      "depth_discontinuity"};

struct ProjectOptions {
  RowMode row_mode = RowMode::Auto;
  std::vector<std::string> extra_channels;  // names from kEffectChannels
  float min_range = 0.f;                    // returns closer than this are ignored (e.g. the car's roof)
};

struct ProjectionResult {
  PolarGridMap pgm;
  RowMode row_mode = RowMode::Auto;      // the mode actually used
  std::vector<std::int64_t> point_cell;  // per input point: row * cols + col, or -1 if not projected
  std::size_t dropped = 0;               // points outside the layout's rows or below min_range
  int firing_order_rows = 0;             // rows the azimuth-wrap cut found (0 if not tried)
};

// Throws lidarsim::Error (naming `source`) for a non-finite coordinate or intensity.
ProjectionResult project(const std::vector<Point>& points, const BeamLayout& layout, const ProjectOptions& options = {},
                         const std::string& source = "point cloud");

// Row of each point by the azimuth-wrap cut (see FiringOrder above); returns the row count.
int firing_order_rows(const std::vector<Point>& points, std::vector<int>& rows);

// Fills the "incidence" channel from the "range" channel along the layout's nominal beam
// directions (adds it if missing); for grids without their points, e.g. simulated ones.
void compute_incidence(PolarGridMap& pgm);

// Fills the "depth_discontinuity" channel from the "range" channel (adds it if missing).
void compute_depth_discontinuity(PolarGridMap& pgm);

// Per point, the value of `plane` ([rows * cols], e.g. a predicted intensity) at the point's cell;
// NaN for points that were not projected (ProjectionResult::dropped of them).
std::vector<float> back_project(const float* plane, const std::vector<std::int64_t>& point_cell);

}  // namespace lidarsim::pgm
